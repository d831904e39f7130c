"""The solid fill stays inside the object (sc3d_data.voxel.voxelize, rule 2).

Winding numbers add up over overlapping sheets: open sheets stacked with the same facing (a car
floor pan modelled as two layers and a plate, all facing into the cabin) reach |w| >= 0.5 in a
slab of empty space on their outer side, also beyond the mesh's bounding box. A voxel is filled
by its winding number only where its centre is spanned: some axis line through it meets the
surface on both sides.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sc3d_data.voxel._ray_kernel import rays_kernel, rays_spans_kernel
from sc3d_data.voxel.voxelize import voxelize_triangles, winding_numbers

G = 32
MESHES = Path(__file__).resolve().parents[2] / "shared" / "meshes"


def sheets(heights, half=0.3):
    """Horizontal squares [-half, half]^2 in x, z at the given heights y, each two triangles
    with normal +y: a floor stacked in layers, all facing the same way."""
    verts, faces = [], []
    for y in heights:
        n = len(verts)
        verts += [[-half, y, -half], [half, y, -half], [half, y, half], [-half, y, half]]
        faces += [[n, n + 2, n + 1], [n, n + 3, n + 2]]  # (b - a) x (c - a) along +y
    return np.array(verts, float), np.array(faces)


def closed_box(lo, hi):
    """Axis-aligned box [lo, hi], 12 triangles with outward normals."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    v = np.array([[(hi if (c >> a) & 1 else lo)[a] for a in range(3)] for c in range(8)])
    f = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6],   # z = lo, z = hi
                  [0, 1, 4], [1, 5, 4], [2, 6, 3], [3, 6, 7],   # y = lo, y = hi
                  [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]])  # x = lo, x = hi
    return v, f


def cells(lo, hi):
    """The voxels an axis-aligned box [lo, hi] touches, its faces strictly inside voxels."""
    a = np.floor((np.asarray(lo, float) + 0.5) * G).astype(int)
    b = np.floor((np.asarray(hi, float) + 0.5) * G).astype(int)
    out = np.zeros((G, G, G), bool)
    out[a[0]:b[0] + 1, a[1]:b[1] + 1, a[2]:b[2] + 1] = True
    return out


def square_winding(half, d):
    """Winding number of a square of side 2 * half, on its axis at distance d on the side its
    normal points away from: solid angle 4 asin(half^2 / (half^2 + d^2)) over 4 pi."""
    return np.arcsin(half ** 2 / (half ** 2 + d ** 2)) / np.pi


HEIGHTS = (0.005, 0.015, 0.025)  # voxel units 16.16, 16.48, 16.8: all three in layer y = 16


def test_closed_box_is_outward_and_spanned_only_inside():
    v, f = closed_box([-0.2, -0.1, -0.15], [0.25, 0.12, 0.3])
    vi = np.ascontiguousarray((v + 0.5) * G)
    nonzero = np.zeros((G, G, G), np.uint8)
    spanned = np.zeros((G, G, G), bool)
    crossings = np.zeros((6, G, G, G), np.int32)
    rays_spans_kernel(vi, f, G, crossings, nonzero, spanned)
    inside = nonzero == 6
    # centres inside [-0.2, 0.25] x [-0.1, 0.12] x [-0.15, 0.3]: x 10..23, y 13..19, z 11..25
    want = np.zeros((G, G, G), bool)
    want[10:24, 13:20, 11:26] = True
    np.testing.assert_array_equal(inside, want)
    np.testing.assert_array_equal(crossings[0][inside], 1)  # outward: +1 where a ray leaves
    # a convex closed surface: a line through an outside centre meets it on one side at most
    np.testing.assert_array_equal(spanned, want)
    alone = np.zeros((G, G, G), np.uint8)
    rays_kernel(vi, f, G, np.zeros((6, 0, 0, 0), np.int32), alone)
    np.testing.assert_array_equal(alone, nonzero)


def test_stacked_sheets_fill_no_space_beyond_them():
    v, f = sheets(HEIGHTS)
    # the cause: below (and above) the stack the three solid angles add up past 0.5,
    # e.g. 0.350 + 0.337 + 0.325 = 1.012 at (0, -0.1, 0), where nothing of the mesh is
    want_w = sum(square_winding(0.3, y + 0.1) for y in HEIGHTS)
    assert 1.0 < want_w < 1.02
    w = winding_numbers(v, f, np.array([[0.0, -0.1, 0.0], [0.0, 0.2, 0.0]]), exact=True)
    np.testing.assert_allclose(w, [want_w, -sum(square_winding(0.3, 0.2 - y) for y in HEIGHTS)],
                               rtol=0, atol=1e-12)
    assert abs(w[1]) > 0.5
    got = voxelize_triangles(v, f)
    # the three sheets touch one voxel layer: y = 16, x and z from floor(0.2 * 32) = 6 to
    # floor(0.8 * 32) = 25; nothing else (before the fix: 4976 more voxels, a lens from layer 7
    # to layer 25, all entirely outside the mesh's bounding box y in [0.005, 0.025])
    np.testing.assert_array_equal(got, cells([-0.3, 0.005, -0.3], [0.3, 0.025, 0.3]))
    assert got.sum() == 20 * 20


def test_stacked_floor_leaves_the_space_under_it_empty_inside_the_bounding_box():
    """A closed "wheel" at one corner reaches below the floor, so the space under the floor down
    to the wheel's bottom lies inside the bounding box: it stays empty all the same."""
    fv, ff = sheets(HEIGHTS)
    wv, wf = closed_box([0.2, -0.2, 0.2], [0.28, 0.02, 0.28])  # voxel units 22.4..24.96, 9.6..16.64
    v, f = np.vstack([fv, wv]), np.vstack([ff, wf + len(fv)])
    got = voxelize_triangles(v, f)
    floor = cells([-0.3, 0.005, -0.3], [0.3, 0.025, 0.3])  # layer y = 16, x and z 6..25
    wheel = cells([0.2, -0.2, 0.2], [0.28, 0.02, 0.28])    # x and z 22..24, y 9..16
    np.testing.assert_array_equal(got, floor | wheel)
    assert got.sum() == 400 + 3 * 7 * 3  # the wheel's 3 x 8 x 3 less its top layer, in the floor
    # under the floor, inside the bounding box (y from -0.2): the winding number says inside
    # (before the fix: 2269 voxels filled in layers 9..15 around the wheel)
    below = np.array([[0.0, -0.5 + 12.5 / G, 0.0]])
    assert winding_numbers(v, f, below, exact=True)[0] > 0.5
    assert not got[6:26, 9:16, 6:22].any()


@pytest.mark.parametrize("name", ["car/concept_sedan_01_katorlegaz.glb", "car/toycar_khronos.glb"])
def test_shared_cars_have_no_voxels_outside_their_bounding_box(name):
    """The two meshes of /work/shared/meshes the fault showed on (739 and 38 voxels entirely
    outside the bounding box, 1069 and 148 removed by the fix in all); skipped without them."""
    path = MESHES / name
    if not path.is_file():
        pytest.skip(f"{path} not present")
    from sc3d_data.geometry.normalize import apply_transform, to_canonical_transform, used_vertices
    from sc3d_data.io.meshes import load_mesh_triangles

    v, f = load_mesh_triangles(path)
    v = apply_transform(v, to_canonical_transform(v, f, "fit", "+Y", "+Z"))
    got = voxelize_triangles(v, f)
    lo, hi = used_vertices(v, f).min(0), used_vertices(v, f).max(0)
    edges = np.arange(G + 1) / G - 0.5
    for a in range(3):
        outside = (edges[1:] < lo[a]) | (edges[:-1] > hi[a])  # whole cell beyond the box
        assert not np.take(got, np.nonzero(outside)[0], axis=a).any(), (name, "xyz"[a])
