"""Far cameras (`render --distance 60 --fov 2`, `--distance 1000 --fov 0.1`: near-orthographic
views, which the option checks accept) keep the depth resolution of the default camera.

The depth buffer has 24 bits; with the near plane fixed at 0.01 its step at the object grows as
distance^2 (2.4e-5 at distance 2, 0.02 at 60, 6 units at 1000), so the stored `depth` was off by
up to 2.6 units with exit 0 and surfaces closer than a step were drawn in the wrong order (56% of
the object pixels of the sample chairs at distance 1000 had another surface's colour). Expected
values are derived by hand: the camera at azimuth 0, elevation 0 sits at (0, 0, d) looking down
-z, so a point at z = 0.1 has camera-frame depth d - 0.1."""
from __future__ import annotations

import numpy as np
import pytest


def _two_squares():
    """Two squares facing +z in one part: blue at z = -0.1 (its triangles first), red at z = +0.1
    (drawn after it: a depth test that cannot tell the two apart keeps the blue one)."""
    import trimesh

    sq = np.array([[-0.2, -0.2, 0.0], [0.2, -0.2, 0.0], [0.2, 0.2, 0.0], [-0.2, 0.2, 0.0]])
    v = np.concatenate([sq + [0, 0, -0.1], sq + [0, 0, 0.1]])
    f = [[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]]
    colors = np.array([[0, 0, 255, 255]] * 4 + [[255, 0, 0, 255]] * 4, dtype=np.uint8)
    return trimesh.Scene(trimesh.Trimesh(v, f, process=False, vertex_colors=colors))


@pytest.mark.parametrize("distance, fov", [(2.0, 10.0), (60.0, 2.0), (1000.0, 0.1)])
def test_depth_and_visibility_of_a_far_camera_are_those_of_the_near_one(distance, fov):
    from sc3d_data.geometry.camera import ViewSettings
    from sc3d_data.render.renderer import MeshRenderer, RenderSettings

    views = ViewSettings(num_views=1, elevations_deg=(0.0,), distance=distance, fov_deg=fov)
    r = MeshRenderer(views, RenderSettings(depth=True))
    try:
        out = r.render(_two_squares(), np.eye(4))
    finally:
        r.close()
    c = views.image_size // 2
    assert out["masks"][0, c, c]
    assert out["depth"][0, c, c] == pytest.approx(distance - 0.1, abs=1e-3)
    red = out["images"][0, c - 2:c + 3, c - 2:c + 3].reshape(-1, 3)
    assert (red[:, 0] > 150).all() and (red[:, 2] == 0).all(), red[:3]


def test_the_default_camera_keeps_its_depth_range():
    """The near plane moves only for cameras farther than the default distance 2: the default
    renders (and every dataset made with them) keep their bytes."""
    from sc3d_data.render.renderer import ZNEAR, depth_range

    assert depth_range(2.0) == (ZNEAR, 12.0)
    assert depth_range(0.9)[0] == ZNEAR
    near, far = depth_range(1000.0)
    assert 1000.0 - near > 3 ** 0.5 / 2 and far > 1000.0 + 3 ** 0.5 / 2
