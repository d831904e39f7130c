"""Write a ``ShapeNetRendering`` + ``ShapeNetVox32`` pair in 3D-R2N2's exact layout from any
meshes, following the conventions of the released files (``docs/data.md``) and
*not* the importer's code, so that ``import-r2n2`` is tested against an independent
statement of them: the test data of ``import-r2n2``, since the release cannot be
downloaded on every machine.

Per model, from a mesh in sc3d's canonical frame (front +Z, fitted to [-0.5, 0.5]^3):

* the "OBJ file" is that mesh as ShapeNetCore v1 stores it: front along +X, +Y up,
  bounding box centred at the origin, longest side ``obj_scale`` (v1 models are about 0.7);
* 24 views at random R2N2-like poses (azimuth uniform in [0, 360), elevation in [25, 30]
  deg, distance ratio in [0.65, 0.9], in-plane 0 unless ``in_plane_max`` > 0), each camera
  built the way 3D-R2N2's Blender script builds it (:func:`blender_camera`), rendered with
  sc3d's renderer at 137x137 and written as RGBA PNGs (alpha = mask);
  ``rendering_metadata.txt`` in R2N2's format (fov column 25, as released) and
  ``renderings.txt``;
* ``model.binvox`` as ``binvox -d 32 -cb`` writes it: the grid is the cube
  ``scale * [-0.5, 0.5]^3`` centred at the OBJ origin (``scale`` = the longest bounding-box
  side) and the header says ``translate`` = the bounding-box minimum, ``scale``.

Creates an OpenGL context: call it in a process that will not fork afterwards (the tests run
it in a subprocess).
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

NUM_VIEWS = 24
IMAGE_SIZE = 137
MAX_CAMERA_DIST = 1.75          # 3D-R2N2 lib/config.py, cfg.RENDERING.MAX_CAMERA_DIST
LENS_MM, SENSOR_MM = 35.0, 32.0  # Blender's default camera
#: canonical (front +Z) -> ShapeNetCore v1 OBJ axes (front +X): (x, y, z) -> (z, y, -x)
CANONICAL_TO_V1 = np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]])
#: Blender's OBJ importer (axis_forward -Z, axis_up Y): OBJ (x, y, z) -> Blender (x, -z, y)
OBJ_TO_BLENDER = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])


def _rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])


def _rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def blender_camera(azimuth: float, elevation: float, in_plane: float, distance_ratio: float
                   ) -> tuple[np.ndarray, np.ndarray]:
    """``(R [3,3], t [3])`` world->camera (OpenCV: x right, y down, z forward) in the OBJ frame
    of one ``rendering_metadata.txt`` line, rebuilt from 3D-R2N2's ``lib/blender_renderer.py``:
    the camera sits at ``(d, 0, 0)`` with Euler ZXY ``(0, 90, 90)`` deg, parented to an empty
    whose Euler XYZ rotation is ``(-in_plane, -elevation, -azimuth)`` deg; Blender cameras look
    down their local -Z with +Y up; the OBJ was imported with ``OBJ_TO_BLENDER``."""
    r = math.radians
    rig = _rz(r(-azimuth)) @ _ry(r(-elevation)) @ _rx(r(-in_plane))   # Euler XYZ: X first
    cam_local = _ry(r(90)) @ _rx(0.0) @ _rz(r(90))                     # Euler ZXY: Z first
    world = rig @ cam_local                        # columns: camera right, up, back (Blender world)
    centre = rig @ np.array([distance_ratio * MAX_CAMERA_DIST, 0.0, 0.0])
    R_blender = np.stack([world[:, 0], -world[:, 1], -world[:, 2]])
    return R_blender @ OBJ_TO_BLENDER, -R_blender @ centre


def blender_focal_px(image_size: int = IMAGE_SIZE) -> float:
    """Focal length in pixels of Blender's default camera (35 mm lens, 32 mm sensor width)."""
    return LENS_MM / SENSOR_MM * image_size


def random_r2n2_poses(rng: np.random.Generator, n: int = NUM_VIEWS, in_plane_max: float = 0.0
                      ) -> np.ndarray:
    """``[n, 5]`` rows ``(azimuth, elevation, in_plane, distance_ratio, fov)`` in R2N2's
    convention and ranges (module doc)."""
    in_plane = rng.uniform(-in_plane_max, in_plane_max, n) if in_plane_max > 0 else np.zeros(n)
    return np.stack([rng.uniform(0, 360, n), rng.uniform(25, 30, n), in_plane,
                     rng.uniform(0.65, 0.9, n), np.full(n, 25.0)], -1)


def synthesize_r2n2(entries, renderings: Path, voxels: Path, seed: int = 0, obj_scale: float = 0.7,
                    in_plane_max: float = 0.0, backend: str = "egl") -> dict:
    """Write the fake data for ``entries`` (``MeshEntry``-like: ``path``, ``category``,
    ``model_id``; meshes in sc3d's canonical orientation). Returns ``{"category/model_id":
    {"metadata": [[5 floats] x 24], "R": ..., "t": ... (true cameras in the OBJ frame),
    "obj_scale", "bbox_min"}}``."""
    from PIL import Image

    from sc3d_data.io.binvox import write_binvox
    from sc3d_data.geometry.camera import ViewSettings, fov_from_focal
    from sc3d_data.io.meshes import load_mesh
    from sc3d_data.geometry.normalize import apply_transform, to_canonical_transform
    from sc3d_data.render.renderer import MeshRenderer, RenderSettings
    from sc3d_data.voxel.voxelize import voxelize_triangles

    rng = np.random.default_rng(seed)
    views = ViewSettings(num_views=NUM_VIEWS, image_size=IMAGE_SIZE, distance=2.0,
                         fov_deg=fov_from_focal(blender_focal_px(), IMAGE_SIZE))
    renderer = MeshRenderer(views, RenderSettings(background=(0, 0, 0)), backend)
    truth = {}
    try:
        for e in entries:
            scene, vertices, faces, _ = load_mesh(Path(e.path), bad_texture="fallback")
            to_obj = np.eye(4)
            to_obj[:3, :3] = obj_scale * CANONICAL_TO_V1
            to_obj = to_obj @ to_canonical_transform(vertices, faces)
            v_obj = apply_transform(vertices, to_obj)
            used = v_obj[np.unique(faces)]
            lo, size = used.min(axis=0), float(np.ptp(used, axis=0).max())
            meta = random_r2n2_poses(rng, in_plane_max=in_plane_max)
            cams = [blender_camera(az, el, ip, ratio) for az, el, ip, ratio, _ in meta]
            R, t = np.stack([c[0] for c in cams]), np.stack([c[1] for c in cams])
            out = renderer.render(scene, to_obj, R, t)
            rdir = Path(renderings) / e.category / e.model_id / "rendering"
            rdir.mkdir(parents=True, exist_ok=True)
            names = [f"{v:02d}.png" for v in range(NUM_VIEWS)]
            for v, name in enumerate(names):
                rgba = np.concatenate([out["images"][v], (out["masks"][v] * 255)[..., None]], -1)
                Image.fromarray(rgba.astype(np.uint8), "RGBA").save(rdir / name)
            (rdir / "renderings.txt").write_text("\n".join(names) + "\n")
            (rdir / "rendering_metadata.txt").write_text(
                "".join(" ".join(repr(float(x)) for x in row) + "\n" for row in meta))
            # binvox -cb: the cube of side `size` centred at the origin, header translate = bbox min
            grid = voxelize_triangles(v_obj / size, faces, resolution=32)
            vdir = Path(voxels) / e.category / e.model_id
            vdir.mkdir(parents=True, exist_ok=True)
            write_binvox(vdir / "model.binvox", grid, translate=tuple(lo), scale=size)
            truth[f"{e.category}/{e.model_id}"] = {"metadata": meta.tolist(), "R": R.tolist(),
                                                   "t": t.tolist(), "obj_scale": size,
                                                   "bbox_min": lo.tolist()}
    finally:
        renderer.close()
    return truth


def main(argv=None) -> None:
    """``python tests/r2n2_synth.py MESHES RENDERINGS VOXELS TRUTH.json [SEED [IN_PLANE_MAX]]``:
    fake data for every mesh under MESHES (``sc3d_data.formats.discover`` layouts)."""
    import sys

    from sc3d_data.formats.discover import discover_meshes

    args = list(sys.argv[1:] if argv is None else argv)
    meshes, renderings, voxels, truth_path = args[:4]
    seed = int(args[4]) if len(args) > 4 else 0
    in_plane_max = float(args[5]) if len(args) > 5 else 0.0
    entries, _ = discover_meshes(meshes)
    truth = synthesize_r2n2(entries, Path(renderings), Path(voxels), seed=seed, in_plane_max=in_plane_max)
    Path(truth_path).write_text(json.dumps(truth))


if __name__ == "__main__":
    import os
    import sys

    main()
    # end as the render workers do: NVIDIA's EGL can crash in its own teardown when a process
    # that held a context exits normally (a failed run with everything written)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)
