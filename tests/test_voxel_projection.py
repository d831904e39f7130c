"""project_voxels against analytic silhouettes (sc3d_data.geometry.projection)."""
from __future__ import annotations

import numpy as np
from matplotlib.path import Path
from scipy.spatial import ConvexHull

from sc3d_data.geometry.camera import ViewSettings, project_points
from sc3d_data.geometry.projection import project_voxels

S = 64


def hull_silhouette(corners, K, R, t):
    uv, _ = project_points(corners, K, R, t)
    poly = Path(uv[ConvexHull(uv).vertices])
    g = np.arange(S) + 0.5
    v, u = np.meshgrid(g, g, indexing="ij")
    return poly.contains_points(np.stack([u.ravel(), v.ravel()], 1)).reshape(S, S)


def test_box_of_voxels_projects_to_the_hull_of_its_corners():
    cams = ViewSettings().cameras()
    vox = np.zeros((32, 32, 32), bool)
    vox[4:20, 8:30, 10:12] = True  # a slab, asymmetric on purpose
    lo, hi = np.array([4, 8, 10]) / 32 - 0.5, np.array([20, 30, 12]) / 32 - 0.5
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    for v in (0, 5, 11, 18):
        K, R, t = cams["K"][v], cams["R"][v], cams["t"][v]
        got = project_voxels(vox, K, R, t, S)
        assert got.shape == (S, S) and got.dtype == bool
        np.testing.assert_array_equal(got, hull_silhouette(corners, K, R, t))


def test_axes_are_not_swapped():
    """A voxel column on +X appears on the image's right from azimuth 0 (camera on +Z,
    OpenCV x right), and moves towards the camera (larger) at azimuth 90."""
    cams = ViewSettings().cameras()
    vox = np.zeros((32, 32, 32), bool)
    vox[28:32, 14:18, 14:18] = True  # near x = +0.5
    front = project_voxels(vox, cams["K"][0], cams["R"][0], cams["t"][0], S)
    cols = np.nonzero(front.any(0))[0]
    assert cols.min() > S / 2
    side = project_voxels(vox, cams["K"][6], cams["R"][6], cams["t"][6], S)  # azimuth 90: camera on +X
    assert side.sum() > front.sum()


def test_empty_grid_and_full_grid():
    cams = ViewSettings().cameras()
    K, R, t = cams["K"][3], cams["R"][3], cams["t"][3]
    assert not project_voxels(np.zeros((32,) * 3, bool), K, R, t, S).any()
    full = project_voxels(np.ones((16,) * 3, bool), K, R, t, S)
    c = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
    np.testing.assert_array_equal(full, hull_silhouette(c, K, R, t))


def test_several_views_at_once():
    from sc3d_data.geometry.projection import project_voxels_views

    cams = ViewSettings().cameras()
    vox = np.zeros((32, 32, 32), bool)
    vox[10:20, 5:9, 12:30] = True
    many = project_voxels_views(vox, cams["K"], cams["R"], cams["t"], S, views=[0, 7])
    assert many.shape == (2, S, S)
    np.testing.assert_array_equal(many[1], project_voxels(vox, cams["K"][7], cams["R"][7], cams["t"][7], S))
