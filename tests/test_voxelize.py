"""Solid voxelization on shapes with exact answers (sc3d_data.voxel.voxelize)."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from sc3d_data.voxel.voxelize import voxel_centers, voxelize_triangles

G = 32


def box_cells(lo, hi, G=G):
    """Expected occupancy of an axis-aligned box [lo, hi] whose faces lie strictly inside
    voxels: every voxel the closed box touches."""
    out = np.zeros((G, G, G), bool)
    a = np.floor((np.asarray(lo) + 0.5) * G).astype(int)
    b = np.floor((np.asarray(hi) + 0.5) * G).astype(int)
    out[a[0]:b[0] + 1, a[1]:b[1] + 1, a[2]:b[2] + 1] = True
    return out


def box(lo, hi):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    m = trimesh.creation.box(extents=hi - lo)
    m.apply_translation((lo + hi) / 2)
    return m


def cube_distance(centres, G=G):
    """Distance from the origin to the nearest point of each voxel cube (for bounds)."""
    h = 0.5 / G
    return np.linalg.norm(np.maximum(np.abs(centres) - h, 0), axis=-1)


def test_cube_exact_and_orientation_free():
    m = box([-0.3] * 3, [0.3] * 3)
    got = voxelize_triangles(m.vertices, m.faces)
    assert got.dtype == bool and got.shape == (G, G, G)
    np.testing.assert_array_equal(got, box_cells([-0.3] * 3, [0.3] * 3))
    assert got.sum() == 20 ** 3  # voxels 6..25 on every axis
    # inverted faces (inside-out mesh) give the same solid
    np.testing.assert_array_equal(voxelize_triangles(m.vertices, m.faces[:, ::-1]), got)


@pytest.mark.parametrize("res,n", [(64, 40), (128, 78)])
def test_cube_higher_resolutions(res, n):
    m = box([-0.3] * 3, [0.3] * 3)
    got = voxelize_triangles(m.vertices, m.faces, resolution=res)
    assert got.shape == (res,) * 3
    np.testing.assert_array_equal(got, box_cells([-0.3] * 3, [0.3] * 3, res))
    assert got.sum() == n ** 3


def test_sphere_between_inscribed_and_circumscribed_balls():
    r = 0.4
    m = trimesh.creation.icosphere(subdivisions=3, radius=r)
    got = voxelize_triangles(m.vertices, m.faces)
    c = voxel_centers(G)
    # the icosphere lies between its inradius and r
    r_in = np.abs((m.triangles_center * m.face_normals).sum(1)).min()
    assert np.all(got[np.linalg.norm(c, axis=-1) <= r_in])      # solid inside
    assert not np.any(got[cube_distance(c) > r])                 # nothing outside the ball
    assert np.all(got[np.abs(np.linalg.norm(c, axis=-1) - r) < 0.5 / G])  # shell touched


def test_torus_hole_stays_empty():
    R, r = 0.3, 0.1
    m = trimesh.creation.torus(major_radius=R, minor_radius=r, major_sections=64, minor_sections=32)
    got = voxelize_triangles(m.vertices, m.faces)
    c = voxel_centers(G)
    axis = int(np.argmin(m.extents))  # the torus' axis
    ring = [i for i in range(3) if i != axis]
    rho = np.linalg.norm(c[..., ring], axis=-1)
    tube = np.sqrt((rho - R) ** 2 + c[..., axis] ** 2)
    assert np.all(got[tube <= 0.9 * r])                 # the tube is solid
    assert not np.any(got[tube > r + np.sqrt(3) / G])    # hole and outside empty
    assert not got[16, 16, 16] and not got[15, 15, 15]  # centre of the hole


def test_thin_plate_and_zero_thickness_sheet_are_one_layer():
    plate = box([-0.3, 0.01, -0.3], [0.3, 0.011, 0.3])  # inside voxel layer j = 16
    got = voxelize_triangles(plate.vertices, plate.faces)
    np.testing.assert_array_equal(got, box_cells([-0.3, 0.01, -0.3], [0.3, 0.011, 0.3]))
    assert got.sum() == 20 * 20 and got[:, 16].sum() == 400
    sheet_v = np.array([[-0.3, 0.01, -0.3], [0.3, 0.01, -0.3], [0.3, 0.01, 0.3], [-0.3, 0.01, 0.3]])
    sheet_f = np.array([[0, 1, 2], [0, 2, 3]])
    np.testing.assert_array_equal(voxelize_triangles(sheet_v, sheet_f), got)


def test_two_overlapping_boxes_give_their_union():
    a, b = box([-0.3] * 3, [0.1] * 3), box([-0.1] * 3, [0.3] * 3)
    m = trimesh.util.concatenate([a, b])  # a soup: both boxes complete, intersecting
    got = voxelize_triangles(m.vertices, m.faces)
    want = box_cells([-0.3] * 3, [0.1] * 3) | box_cells([-0.1] * 3, [0.3] * 3)
    np.testing.assert_array_equal(got, want)


def test_box_with_one_face_deleted_is_solid():
    # floor at y = -0.21: the centres of its voxel layer (y = -0.203) are inside the box, so the
    # closed box and the box without its floor have the same occupancy
    m = box([-0.3, -0.21, -0.3], [0.3, 0.2, 0.3])
    floor = np.nonzero(m.face_normals[:, 1] < -0.9)[0]  # a car body without a floor
    assert len(floor) == 2
    faces = np.delete(m.faces, floor, axis=0)
    got = voxelize_triangles(m.vertices, faces)
    np.testing.assert_array_equal(got, box_cells([-0.3, -0.21, -0.3], [0.3, 0.2, 0.3]))


def test_large_open_slit_is_solid():
    m = trimesh.creation.cylinder(radius=0.35, height=0.7, sections=64)
    closed = voxelize_triangles(m.vertices, m.faces)
    # remove a 45-degree wedge of the side wall over the full height: a large open slit
    centers = m.triangles_center
    side = np.abs(m.face_normals[:, 2]) < 0.5
    angle = np.degrees(np.arctan2(centers[:, 1], centers[:, 0]))
    slit = side & (np.abs(angle) < 22.5)
    assert slit.sum() >= 8
    got = voxelize_triangles(m.vertices, m.faces[~slit])
    # exact except where the removed wall itself was (its voxels may go either way)
    wall = voxelize_triangles(m.vertices, m.faces[slit])
    wall_layer = wall | np.roll(wall, 1, 0) | np.roll(wall, -1, 0)
    assert np.array_equal(got & ~wall_layer, closed & ~wall_layer)
    assert (closed & ~got).sum() <= wall.sum()
    assert got.sum() > 0.97 * closed.sum()


def test_geometry_outside_the_grid_is_clipped_and_bad_input_is_rejected():
    m = box([-0.3] * 3, [0.8, 0.3, 0.3])
    got = voxelize_triangles(m.vertices, m.faces)
    assert got[-1].any() and got.sum() == (32 - 6) * 20 * 20
    with pytest.raises(ValueError, match="faces"):
        voxelize_triangles(np.zeros((3, 3)), np.zeros((0, 3), int))
    with pytest.raises(ValueError, match="out of range"):
        voxelize_triangles(np.zeros((3, 3)), np.array([[0, 1, 5]]))
    with pytest.raises(ValueError, match="NaN"):
        voxelize_triangles(np.full((3, 3), np.nan), np.array([[0, 1, 2]]))
