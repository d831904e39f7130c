"""Renderer, mesh loading and normalisation on the bundled sample meshes (real EGL/OSMesa
renderer, real HDF5 shards from the session fixture ``sample_shards``)."""
from __future__ import annotations

import h5py
import numpy as np
import pytest
from scipy.ndimage import binary_dilation

from sc3d_data.geometry.camera import DEFAULT_IMAGE_SIZE, project_points
from sc3d_data.io.meshes import DEFAULT_MAX_FACES, MeshError, load_mesh_triangles, validate_triangles
from sc3d_data.geometry.normalize import apply_transform, canonical_rotation, to_canonical_transform
from sc3d_data.io.shards import load_index
from sc3d_data.io.shard_reader import iter_objects


def test_shapes_dtypes_and_nonempty_masks(sample_shards):
    index = load_index(sample_shards)
    assert index["complete"] and index["counts"]["total"] == 11 and index["failures"] == []
    assert index["settings"]["num_views"] == 24 and index["settings"]["backend"] in ("egl", "osmesa")
    S = DEFAULT_IMAGE_SIZE
    expected = {"images": ((24, S, S, 3), np.uint8), "masks": ((24, S, S), np.uint8),
                "K": ((24, 3, 3), np.float32), "R": ((24, 3, 3), np.float32), "t": ((24, 3), np.float32),
                "azimuth": ((24,), np.float32), "elevation": ((24,), np.float32),
                "distance": ((24,), np.float32), "clipped": ((24,), np.uint8),
                "to_canonical": ((4, 4), np.float64), "voxels": ((32, 32, 32), np.uint8)}
    n = 0
    for obj in iter_objects(sample_shards):
        n += 1
        for name, (shape, dtype) in expected.items():
            assert obj[name].shape == shape and obj[name].dtype == dtype, name
        masks = obj["masks"].astype(bool)
        assert masks.reshape(24, -1).any(1).all(), f"{obj['model_id']}: a view with an empty mask"
        # RGB agrees with the mask: background colour exactly outside, object colours inside
        assert (obj["images"][~masks] == 255).all()
        assert (obj["images"][masks] != 255).any(-1).mean() > 0.5
        assert not obj["clipped"].any()
        np.testing.assert_allclose(obj["azimuth"], np.arange(24) * 15.0)
    assert n == 11
    with h5py.File(sample_shards / index["shards"][0]["file"]) as f:
        # one view per chunk (the default "chunks" setting, recorded; docs/benchmarks.md)
        assert f["images"].chunks == (1, 1, S, S, 3) and f["images"].compression == "gzip"
        assert f["masks"].chunks == (1, 1, S, S) and f["voxels"].chunks == (1, 32, 32, 32)
        assert index["settings"]["chunks"] == "view"
        assert "settings" in f.attrs and "schema_version" in f.attrs


def test_projected_vertices_fall_on_masks(sample_shards):
    """Vertices of the source mesh, moved by the stored to_canonical and projected with the
    stored K, R, t, land on the rendered silhouette; flipping image y would not."""
    checked = 0
    for obj in iter_objects(sample_shards, fields=("masks", "K", "R", "t", "to_canonical")):
        if obj["category"] not in ("02958343", "03001627"):  # cars and chairs: no sub-pixel wings
            continue
        v, f = load_mesh_triangles(obj["source"])
        pts = apply_transform(v[np.unique(f)], obj["to_canonical"])
        hit, flipped = [], []
        for k in range(24):
            uv, z = project_points(pts, obj["K"][k].astype(np.float64), obj["R"][k].astype(np.float64),
                                   obj["t"][k].astype(np.float64))
            assert (z > 0).all()
            ij = np.clip(np.floor(uv).astype(int), 0, DEFAULT_IMAGE_SIZE - 1)
            m = binary_dilation(obj["masks"][k].astype(bool))  # vertices on thin parts: 1 px slack
            hit.append(m[ij[:, 1], ij[:, 0]].mean())
            flipped.append(m[DEFAULT_IMAGE_SIZE - 1 - ij[:, 1], ij[:, 0]].mean())
        assert np.median(hit) > 0.97, (obj["model_id"], np.median(hit))
        assert np.median(flipped) < 0.9
        checked += 1
    assert checked >= 4


def test_normalize_fit_diagonal_and_axes():
    rng = np.random.default_rng(0)
    v = rng.normal(size=(100, 3)) * [3.0, 1.0, 0.5] + [10, -2, 4]
    T = to_canonical_transform(v, mode="fit")
    w = apply_transform(v, T)
    np.testing.assert_allclose((w.max(0) + w.min(0)) / 2, 0, atol=1e-12)
    assert np.isclose((w.max(0) - w.min(0)).max(), 1.0)
    w = apply_transform(v, to_canonical_transform(v, mode="diagonal"))
    assert np.isclose(np.linalg.norm(w.max(0) - w.min(0)), 1.0)
    R = canonical_rotation(up="+Z", front="-X")
    np.testing.assert_allclose(R @ [0, 0, 1], [0, 1, 0])
    np.testing.assert_allclose(R @ [-1, 0, 0], [0, 0, 1])
    assert np.isclose(np.linalg.det(R), 1.0)
    with pytest.raises(ValueError):
        canonical_rotation(up="+Y", front="-Y")


def test_default_face_limit_rejects_two_million_faces():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.float64)
    validate_triangles(v, np.zeros((DEFAULT_MAX_FACES, 3), np.int64) + [0, 1, 2], "ok.obj")
    with pytest.raises(MeshError, match="more than the limit"):
        validate_triangles(v, np.zeros((2_000_000, 3), np.int64) + [0, 1, 2], "huge.obj")


def test_resolve_backend_probes_the_renderer_in_a_subprocess():
    """``auto`` finds a backend by rendering a box with sc3d's renderer in a child process (this
    process never gets a GL context) and reports the driver that drew it; unknown names are
    refused. The child's verdict is the line it prints after rendering: it ends with
    ``os._exit`` (NVIDIA's EGL can crash in its teardown at a normal exit)."""
    from sc3d_data.render.probe import probe_backend, resolve_backend

    name, renderer = probe_backend("auto")
    assert name in ("egl", "osmesa") and renderer  # e.g. "llvmpipe (LLVM 15.0.6, 256 bits)"
    assert resolve_backend(name) == name
    with pytest.raises(ValueError):
        resolve_backend("vulkan")


def test_raster_tolerance_allows_edge_pixels_and_one_step_of_colour_only():
    """The tolerance the GPU-vs-llvmpipe comparisons use (tests/conftest.py) passes a mask that
    differs along its outline and colours off by one, and fails a mask moved by two pixels or a
    colour off by two (its negative control)."""
    from conftest import assert_same_raster

    m = np.zeros((1, 16, 16), np.uint8)
    m[0, 4:12, 4:12] = 1
    img = np.where(m[..., None] > 0, 120, 255).astype(np.uint8).repeat(3, -1)
    grown = m.copy()
    grown[0, 3, 5:9] = 1  # one more row of pixels along the top edge
    assert_same_raster(img, m, np.clip(img.astype(int) + (m[..., None] > 0), 0, 255), grown)
    moved = np.roll(m, 2, axis=-1)
    with pytest.raises(AssertionError, match="mask pixels differ away"):
        assert_same_raster(img, m, np.where(moved[..., None] > 0, 120, 255).repeat(3, -1), moved)
    with pytest.raises(AssertionError, match="differs by 2"):
        assert_same_raster(img, m, np.where(m[..., None] > 0, 122, 255).repeat(3, -1), m)


def _facing_square(**visual):
    """A unit square in the plane z = 0 (normal +z), as a one-part ``trimesh.Scene``."""
    import trimesh

    v = np.array([[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.5, 0.5, 0.0], [-0.5, 0.5, 0.0]])
    return trimesh.Scene(trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3]], process=False, **visual))


def test_shading_of_grey_vertex_colour_and_texture_matches_the_hand_derived_model():
    """The centre pixel of a square seen face-on (|n.z| = 1) by a camera on the +z axis, against
    the module doc's model worked out by hand: c = base x (ambient + intensity / pi), then
    c^(1/2.2) x 255 rounded. Ambient 0.2, intensity 1.5: 0.2 + 1.5 / pi = 0.67746.
    - no material: base 0.3 -> 0.20324 -> 0.48468 -> 123.59 -> 124
    - red vertex colours (255, 0, 0): base (1, 0, 0) -> 0.67746 -> 0.83778 -> 213.63 -> 214
    - a uniform sRGB 128 texture (PBR, colour factor 1): linear ((128/255 + 0.055) / 1.055)^2.4
      = 0.21586 -> 0.14624 -> 0.41733 -> 106.42 -> 106 (the texture path also covers uv upload)
    Each case is drawn by its own shader variant (renderer._VARIANT_DEFINES)."""
    import trimesh
    from PIL import Image

    from sc3d_data.geometry.camera import ViewSettings
    from sc3d_data.render.renderer import MeshRenderer

    views = ViewSettings(num_views=4)
    r = MeshRenderer(views)
    try:
        # OpenCV world->camera: camera at (0, 0, 2) looking down -z, image y = -world y
        R = np.repeat(np.diag([1.0, -1.0, -1.0])[None], 4, axis=0)
        t = np.repeat(np.array([[0.0, 0.0, 2.0]]), 4, axis=0)
        S = views.image_size
        uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
        grey_tex = trimesh.visual.TextureVisuals(uv=uv, material=trimesh.visual.material.PBRMaterial(
            baseColorTexture=Image.new("RGB", (4, 4), (128, 128, 128)), baseColorFactor=[255, 255, 255, 255]))
        cases = {"no material": (_facing_square(), [124, 124, 124]),
                 "vertex colours": (_facing_square(vertex_colors=np.tile([255, 0, 0, 255], (4, 1))), [214, 0, 0]),
                 "texture": (_facing_square(visual=grey_tex), [106, 106, 106])}
        for name, (scene, expected) in cases.items():
            out = r.render(scene, np.eye(4), R=R, t=t)
            centre = out["images"][:, S // 2, S // 2].astype(int)
            # within 1 per 8-bit channel: GL leaves the shader's rounding to the driver (llvmpipe
            # gives these values exactly, NVIDIA's may differ by one)
            assert (np.abs(centre - expected) <= 1).all(), (name, centre[0], expected)
            assert out["masks"][:, S // 2, S // 2].all() and not out["masks"][:, 0, 0].any()
        # the default cameras are back after a call with explicit ones: view 0 is not face-on
        plain = r.render(cases["no material"][0], np.eye(4))["images"][0].astype(int)
        assert not (np.abs(plain - 124) <= 1).all(axis=-1).any()
    finally:
        r.close()


def test_parts_sharing_one_texture_image_upload_it_once_and_each_part_draws_its_own():
    """Three squares seen face-on, the first and third sharing one PIL image (red), the second
    with its own (blue): as a GLB whose parts share a material. The image is uploaded once per
    object (two textures made, not three), and each square's centre has its own texture's colour
    by the hand-derived model of the test above: sRGB 255 -> linear 1 -> 0.67746 -> 214 (the
    third square drawn red after the blue one, so the shared texture is bound again)."""
    import trimesh
    from PIL import Image

    from sc3d_data.geometry.camera import ViewSettings
    from sc3d_data.render.renderer import MeshRenderer

    red, blue = Image.new("RGB", (4, 4), (255, 0, 0)), Image.new("RGB", (4, 4), (0, 0, 255))
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    scene, centres = trimesh.Scene(), (-0.4, 0.0, 0.4)
    for i, (x, image) in enumerate(zip(centres, (red, blue, red))):
        v = np.array([[-0.15, -0.15, 0.0], [0.15, -0.15, 0.0], [0.15, 0.15, 0.0], [-0.15, 0.15, 0.0]]) + [x, 0, 0]
        visual = trimesh.visual.TextureVisuals(uv=uv, material=trimesh.visual.material.PBRMaterial(
            baseColorTexture=image, baseColorFactor=[255, 255, 255, 255]))
        scene.add_geometry(trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3]], process=False, visual=visual), f"part{i}")
    views = ViewSettings(num_views=4)
    r = MeshRenderer(views)
    made = []
    texture = r._texture
    r._texture = lambda image, wrap: made.append(image) or texture(image, wrap)
    try:
        R = np.repeat(np.diag([1.0, -1.0, -1.0])[None], 4, axis=0)  # camera at (0, 0, 2) looking down -z
        t = np.repeat(np.array([[0.0, 0.0, 2.0]]), 4, axis=0)
        out = r.render(scene, np.eye(4), R=R, t=t)
    finally:
        r.close()
    assert len(made) == 2 and made[0] is red and made[1] is blue
    K = views.cameras()["K"][0]
    for x, expected in zip(centres, ([214, 0, 0], [0, 0, 214], [214, 0, 0])):
        u, v = int(K[0, 0] * x / 2 + K[0, 2]), int(K[1, 2])
        pixel = out["images"][0, v, u].astype(int)
        assert (np.abs(pixel - expected) <= 1).all(), (x, pixel, expected)


def test_parts_with_and_without_vertex_colours_each_draw_their_own_data():
    """All parts' vertex data go into shared buffers at per-part offsets (``MeshRenderer._upload``):
    three squares, red vertex colours, none (grey), blue vertex colours, each at its own place
    with its own colour by the hand-derived model above (red 214, grey 124, blue 214): the
    third part's colours come after the first's though the second has none."""
    import trimesh

    from sc3d_data.geometry.camera import ViewSettings
    from sc3d_data.render.renderer import MeshRenderer

    scene, centres = trimesh.Scene(), (-0.4, 0.0, 0.4)
    for i, (x, colour) in enumerate(zip(centres, ([255, 0, 0, 255], None, [0, 0, 255, 255]))):
        v = np.array([[-0.15, -0.15, 0.0], [0.15, -0.15, 0.0], [0.15, 0.15, 0.0], [-0.15, 0.15, 0.0]]) + [x, 0, 0]
        visual = {} if colour is None else {"vertex_colors": np.tile(colour, (4, 1))}
        scene.add_geometry(trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3]], process=False, **visual), f"part{i}")
    views = ViewSettings(num_views=4)
    r = MeshRenderer(views)
    try:
        R = np.repeat(np.diag([1.0, -1.0, -1.0])[None], 4, axis=0)  # camera at (0, 0, 2) looking down -z
        out = r.render(scene, np.eye(4), R=R, t=np.repeat(np.array([[0.0, 0.0, 2.0]]), 4, axis=0))
    finally:
        r.close()
    K = views.cameras()["K"][0]
    for x, expected in zip(centres, ([214, 0, 0], [124, 124, 124], [0, 0, 214])):
        pixel = out["images"][0, int(K[1, 2]), int(K[0, 0] * x / 2 + K[0, 2])].astype(int)
        assert (np.abs(pixel - expected) <= 1).all(), (x, pixel, expected)


def test_a_draw_not_read_is_dropped_by_the_next_and_read_needs_a_draw():
    """``draw`` then ``read`` (the job voxelizes between them): after an object interrupted
    between the two, the next object's pixels are its own (a cube, not the first object's
    sphere, whose silhouettes differ); a ``read`` without a ``draw`` is an error, not stale pixels."""
    import trimesh

    from sc3d_data.geometry.camera import ViewSettings
    from sc3d_data.render.renderer import MeshRenderer

    r = MeshRenderer(ViewSettings(num_views=4))
    try:
        sphere = trimesh.Scene(trimesh.creation.icosphere(radius=0.4))
        cube = trimesh.Scene(trimesh.creation.box(extents=(0.8, 0.8, 0.8)))
        alone = r.render(cube, np.eye(4))
        r.draw(sphere, np.eye(4))
        r.draw(cube, np.eye(4))
        after = r.read()
        assert (after["masks"] == alone["masks"]).all() and (after["images"] == alone["images"]).all()
        assert (r.render(sphere, np.eye(4))["masks"] != alone["masks"]).any()
        with pytest.raises(RuntimeError, match="without draw"):
            r.read()
    finally:
        r.close()


def test_validate_triangles_keeps_the_triangles_with_area():
    """A mesh whose only triangle with area comes after 4,096 triangles with three equal corners
    keeps that one triangle (the right triangle (0,0,0) (1,0,0) (0,1,0), area 1/2); the same
    without it has no area and is refused."""
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    flat = np.zeros((4096, 3), dtype=np.int64)
    assert validate_triangles(v, np.concatenate([flat, [[0, 1, 2]]])).tolist() == [[0, 1, 2]]
    with pytest.raises(MeshError, match="zero surface area"):
        validate_triangles(v, flat)


def test_used_vertices_are_the_rows_np_unique_names_in_index_order():
    from sc3d_data.geometry.normalize import used_vertices

    rng = np.random.default_rng(3)
    vertices = rng.normal(size=(50, 3))
    faces = rng.integers(5, 40, size=(30, 3))  # vertices 0-4 and 40-49 are not used
    np.testing.assert_array_equal(used_vertices(vertices, faces), vertices[np.unique(faces)])
    assert len(used_vertices(vertices, [[2, 2, 7]])) == 2
