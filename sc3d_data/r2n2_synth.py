"""Write a ``ShapeNetRendering`` + ``ShapeNetVox32`` pair in 3D-R2N2's exact layout from any
meshes, with cameras chosen here (so they are known): the test data of ``import-r2n2``, since
the released data cannot be downloaded on every machine.

Per model: 24 views at random R2N2-like poses (azimuth uniform in [0, 360), elevation in
[25, 30] deg, distance ratio in [0.65, 0.9], in-plane 0), rendered with sc3d's renderer at
137x137 with Blender's default lens (fov 49.13 deg) and written as RGBA PNGs (alpha = mask),
``rendering_metadata.txt`` in R2N2's format (fov column 25, as released) and
``renderings.txt``; voxels (sc3d's voxelizer, 32^3) as ``model.binvox``.

The "OBJ frame" of the fake data is sc3d's canonical frame scaled by ``obj_scale`` (default
0.7, roughly the size of ShapeNetCore v1 models), so the binvox header is
``translate = -obj_scale/2``, ``scale = obj_scale`` and the import must undo that scale.

Creates an OpenGL context: call it in a process that will not fork afterwards (the tests run
it in a subprocess).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from sc3d_data import camera
from sc3d_data.r2n2_import import (R2N2_FOV_DEG, R2N2_IMAGE_SIZE, R2N2_MAX_CAMERA_DISTANCE,
                                   R2N2_NUM_VIEWS, sc3d_to_r2n2_azimuth)


def random_r2n2_poses(rng: np.random.Generator, n: int = R2N2_NUM_VIEWS) -> np.ndarray:
    """``[n, 5]`` rows ``(azimuth, elevation, in_plane, distance_ratio, fov)`` in R2N2's
    convention and ranges (see module doc)."""
    return np.stack([rng.uniform(0, 360, n), rng.uniform(25, 30, n), np.zeros(n),
                     rng.uniform(0.65, 0.9, n), np.full(n, 25.0)], -1)


def synthesize_r2n2(entries, renderings: Path, voxels: Path, seed: int = 0, obj_scale: float = 0.7,
                    backend: str = "egl") -> dict:
    """Write the fake data for ``entries`` (``MeshEntry``-like: ``path``, ``category``,
    ``model_id``). Returns ``{"category/model_id": {"metadata": [[5 floats] x 24],
    "R": [...], "t": [...]}}``: the true cameras in the OBJ frame (OpenCV, as in
    ``sc3d_data.camera``)."""
    from PIL import Image

    from sc3d_data.binvox import write_binvox
    from sc3d_data.mesh_io import load_mesh
    from sc3d_data.normalize import apply_transform, to_canonical_transform
    from sc3d_data.render import MeshRenderer, RenderSettings
    from sc3d_data.voxelize import voxelize_triangles

    rng = np.random.default_rng(seed)
    views = camera.ViewSettings(num_views=R2N2_NUM_VIEWS, image_size=R2N2_IMAGE_SIZE,
                                fov_deg=R2N2_FOV_DEG, distance=2.0)
    renderer = MeshRenderer(views, RenderSettings(background=(0, 0, 0)), backend)
    truth = {}
    try:
        for e in entries:
            scene, vertices, faces, _ = load_mesh(Path(e.path), bad_texture="fallback")
            to_can = to_canonical_transform(vertices, faces)
            to_obj = np.diag([obj_scale, obj_scale, obj_scale, 1.0]) @ to_can
            meta = random_r2n2_poses(rng)
            R, t = camera.extrinsics(sc3d_to_r2n2_azimuth(meta[:, 0]), meta[:, 1],
                                     meta[:, 3] * R2N2_MAX_CAMERA_DISTANCE, roll_deg=meta[:, 2])
            out = renderer.render(scene, to_obj, R, t)
            rdir = Path(renderings) / e.category / e.model_id / "rendering"
            rdir.mkdir(parents=True, exist_ok=True)
            names = [f"{v:02d}.png" for v in range(R2N2_NUM_VIEWS)]
            for v, name in enumerate(names):
                rgba = np.concatenate([out["images"][v], (out["masks"][v] * 255)[..., None]], -1)
                Image.fromarray(rgba.astype(np.uint8), "RGBA").save(rdir / name)
            (rdir / "renderings.txt").write_text("\n".join(names) + "\n")
            (rdir / "rendering_metadata.txt").write_text(
                "".join(" ".join(repr(float(x)) if i != 2 else "0" for i, x in enumerate(row)) + "\n"
                        for row in meta))
            grid = voxelize_triangles(apply_transform(vertices, to_can), faces, resolution=32)
            vdir = Path(voxels) / e.category / e.model_id
            vdir.mkdir(parents=True, exist_ok=True)
            write_binvox(vdir / "model.binvox", grid, translate=(-obj_scale / 2,) * 3, scale=obj_scale)
            truth[f"{e.category}/{e.model_id}"] = {"metadata": meta.tolist(), "R": R.tolist(),
                                                   "t": t.tolist(), "obj_scale": obj_scale}
    finally:
        renderer.close()
    return truth


def main(argv=None) -> None:
    """``python -m sc3d_data.r2n2_synth MESHES RENDERINGS VOXELS TRUTH.json [SEED]``: fake data
    for every mesh under MESHES (``sc3d_data.discover`` layouts)."""
    import sys

    from sc3d_data.discover import discover_meshes

    args = list(sys.argv[1:] if argv is None else argv)
    meshes, renderings, voxels, truth_path = args[:4]
    seed = int(args[4]) if len(args) > 4 else 0
    entries, _ = discover_meshes(meshes)
    truth = synthesize_r2n2(entries, Path(renderings), Path(voxels), seed=seed)
    Path(truth_path).write_text(json.dumps(truth))


if __name__ == "__main__":
    main()
