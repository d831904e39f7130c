"""3D-R2N2's released data (``ShapeNetRendering`` + ``ShapeNetVox32``): its layout, metadata,
cameras, voxel placement and images, read into sc3d's conventions.

Input layout (Choy et al. 2016)::

    ShapeNetRendering/SYNSET/MODEL_ID/rendering/00.png ... 23.png   137x137 RGBA
    ShapeNetRendering/SYNSET/MODEL_ID/rendering/renderings.txt      PNG names, one per view
    ShapeNetRendering/SYNSET/MODEL_ID/rendering/rendering_metadata.txt
    ShapeNetVox32/SYNSET/MODEL_ID/model.binvox                      32^3

``rendering_metadata.txt`` has one line per view: ``azimuth elevation in_plane distance_ratio
fov`` (degrees, degrees, degrees, fraction, degrees). Every convention below is stated with its
source in ``docs/data.md``; in short:

* camera (3D-R2N2 ``lib/blender_renderer.py``): distance = ``distance_ratio * 1.75``, looking
  at the origin of the ShapeNet OBJ frame; Blender's default camera, 35 mm lens on a 32 mm
  sensor, i.e. ``f = 35/32 * W`` pixels (the ``fov`` column, 25, is not what Blender used and
  is ignored); in the OBJ frame the camera centre is ``d (cos el cos az, sin el, cos el sin az)``
  (OBJ imported into Blender as ``(x, y, z) -> (x, -z, y)``), +Y up in the image, and the image
  is rolled by ``-in_plane`` (Blender rotates the camera rig by ``-yaw``);
* voxels (ShapeNetVox32, ``binvox -d 32 -cb``): ``-cb`` centres the model in the grid but the
  header keeps ``translate`` = the mesh's bounding-box minimum, so the true grid is the cube
  ``scale * [-0.5, 0.5]^3`` centred at the OBJ origin (``voxel_frame="cube"``, the default).
  ``"header"`` takes the header literally (``translate + scale * [0, 1]^3``: binvox files
  written without ``-cb``, e.g. sc3d's own), ``"unit"`` ignores it (``[-0.5, 0.5]^3``);
* front: ShapeNetCore v1 models (the frame of the released renders and voxels) face +X with +Y
  up (R2N2 azimuth 0 shows the front); sc3d's canonical front is +Z, so the canonical frame is
  ``p_can = A (p_obj - c) / size`` with ``A`` the rotation taking ``front`` (default ``"+X"``)
  to +Z and +Y to +Y, ``c``/``size`` the grid's centre and side. With the defaults
  ``A: (x, y, z) -> (-z, y, x)`` and **sc3d azimuth = -R2N2 azimuth** (mod 360).

Cameras are built in the OBJ frame and moved into the canonical one (``R' = R A^T``,
``t' = (R c + t) / size``); voxels are re-indexed by the same rotation. ``azimuth``,
``elevation`` and ``distance`` are read back from the canonical camera centre.
``sc3d-data check`` on the result is the test that all of this was read right.

Images: premultiplied RGB and alpha are area-averaged (PIL box filter) to the target size,
mask = alpha >= 0.5, RGB = composited over the background colour.

The import job (settings, plan, parts, shards and index) is ``sc3d_data.pipeline.jobs.r2n2_job``.

Length: one module because every 3D-R2N2 convention (metadata columns, Blender camera, binvox
placement, v1 front axis) is read in one place next to the code that applies it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sc3d_data.geometry import camera
from sc3d_data.geometry.normalize import canonical_rotation
from sc3d_data.formats.shapenet import is_synset_id, resolve_categories

R2N2_NUM_VIEWS = 24
R2N2_IMAGE_SIZE = 137
R2N2_VOXEL_RESOLUTION = 32
R2N2_MAX_CAMERA_DISTANCE = 1.75
BLENDER_LENS_MM = 35.0
BLENDER_SENSOR_MM = 32.0
#: horizontal field of view of Blender's default camera (degrees): 2 atan(16 / 35) = 49.13
R2N2_FOV_DEG = float(np.rad2deg(2.0 * math.atan(BLENDER_SENSOR_MM / 2.0 / BLENDER_LENS_MM)))
VOXEL_FRAMES = ("cube", "header", "unit")
#: front axis of ShapeNetCore v1 OBJ files, the frame of ShapeNetRendering and ShapeNetVox32
R2N2_FRONT = "+X"
MASK_THRESHOLD = 0.5


@dataclass(frozen=True)
class R2N2View:
    """One line of ``rendering_metadata.txt`` (raw values as released)."""

    azimuth: float        # degrees, 3D-R2N2 convention (see module doc)
    elevation: float      # degrees
    in_plane: float       # degrees
    distance_ratio: float  # distance / 1.75
    fov: float            # degrees; not what Blender used (see module doc)


def parse_metadata_line(line: str) -> R2N2View:
    """Parse ``"az el in_plane ratio fov"``; ``ValueError`` naming the problem otherwise."""
    fields = line.split()
    if len(fields) != 5:
        raise ValueError(f"expected 5 numbers (azimuth elevation in_plane distance_ratio fov), "
                         f"got {len(fields)}: {line.strip()!r}")
    try:
        values = [float(f) for f in fields]
    except ValueError:
        raise ValueError(f"not numbers: {line.strip()!r}") from None
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"non-finite value: {line.strip()!r}")
    if values[3] <= 0:
        raise ValueError(f"distance ratio must be > 0: {line.strip()!r}")
    return R2N2View(*values)


def read_rendering_metadata(path: Path, num_views: int = R2N2_NUM_VIEWS) -> list[R2N2View]:
    """All views of one ``rendering_metadata.txt``; ``ValueError`` naming the file and line of
    the first problem (missing file, malformed line, wrong number of lines)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: missing")
    lines = [ln for ln in path.read_text(errors="replace").splitlines() if ln.strip()]
    views = []
    for i, line in enumerate(lines, 1):
        try:
            views.append(parse_metadata_line(line))
        except ValueError as e:
            raise ValueError(f"{path}:{i}: {e}") from None
    if len(views) != num_views:
        raise ValueError(f"{path}: {len(views)} metadata lines, expected {num_views}")
    return views


def read_rendering_list(rendering_dir: Path, num_views: int = R2N2_NUM_VIEWS) -> list[str]:
    """PNG names of the views in order: ``renderings.txt`` when present, else ``00.png``...
    A line that is not a plain file name (a path: ``/abs.png``, ``../x.png``, ``a/b.png``) is
    refused with ``ValueError`` naming the file and line, so the list cannot make the import
    read an image from outside the model's ``rendering/`` folder; so is a name listed twice (two
    views would hold one picture under two cameras)."""
    lst = Path(rendering_dir) / "renderings.txt"
    if lst.is_file():
        lines = [(k, ln.strip()) for k, ln in enumerate(lst.read_text(errors="replace").splitlines(), 1)]
        names = [name for _, name in lines if name]
        if len(names) != num_views:
            raise ValueError(f"{lst}: {len(names)} names, expected {num_views}")
        seen: dict[str, int] = {}
        for k, name in lines:
            if name and (Path(name).name != name or name == ".."):
                raise ValueError(f"{lst}: line {k}: {name!r} is a path, not a file name in {rendering_dir}; refused")
            if name in seen:  # two views cannot show one picture from two cameras
                raise ValueError(f"{lst}: line {k}: {name!r} is named again (line {seen[name]}); each view needs its own image")
            if name:
                seen[name] = k
        return names
    return [f"{i:02d}.png" for i in range(num_views)]


# ----------------------------------------------------------------------------- cameras
def r2n2_intrinsics(image_size: int) -> np.ndarray:
    """``K`` [3,3] of Blender's default 35 mm / 32 mm camera at ``image_size`` pixels
    (``f = 35/32 * image_size``, principal point at the image centre)."""
    return camera.intrinsics(image_size, R2N2_FOV_DEG)


def r2n2_obj_extrinsics(views: list[R2N2View]) -> tuple[np.ndarray, np.ndarray]:
    """``(R [V,3,3], t [V,3])`` world->camera (OpenCV) of ``views`` in the ShapeNet OBJ frame
    (units of the OBJ file). Camera centre ``d (cos el cos az, sin el, cos el sin az)`` is
    sc3d's look-at camera at azimuth ``90 - az``; the image is rolled by ``-in_plane``."""
    az = np.array([v.azimuth for v in views], dtype=np.float64)
    el = np.array([v.elevation for v in views], dtype=np.float64)
    dist = np.array([v.distance_ratio for v in views]) * R2N2_MAX_CAMERA_DISTANCE
    roll = -np.array([v.in_plane for v in views], dtype=np.float64)
    return camera.extrinsics(90.0 - az, el, dist, roll_deg=roll)


def grid_placement(translate, scale: float, voxel_frame: str = "cube") -> tuple[np.ndarray, float]:
    """``(centre [3], size)``: a binvox grid covers ``centre + size * [-0.5, 0.5]^3`` of the OBJ
    frame, per ``voxel_frame`` (module doc): ``cube`` -> ``(0, scale)``, ``header`` ->
    ``(translate + scale / 2, scale)``, ``unit`` -> ``(0, 1)``."""
    if voxel_frame == "cube":
        return np.zeros(3), float(scale)
    if voxel_frame == "header":
        return np.asarray(translate, dtype=np.float64) + float(scale) / 2.0, float(scale)
    if voxel_frame == "unit":
        return np.zeros(3), 1.0
    raise ValueError(f"voxel_frame must be one of {VOXEL_FRAMES}, not {voxel_frame!r}")


def obj_to_canonical(centre, size: float, front: str = R2N2_FRONT) -> np.ndarray:
    """4x4 OBJ -> canonical matrix ``p_can = A (p_obj - centre) / size`` with ``A`` taking the
    source ``front`` axis to +Z and +Y to +Y (``sc3d_data.geometry.normalize.canonical_rotation``)."""
    A = canonical_rotation("+Y", front)
    M = np.eye(4)
    M[:3, :3] = A / float(size)
    M[:3, 3] = -(A @ np.asarray(centre, dtype=np.float64)) / float(size)
    return M


def rotate_grid(grid: np.ndarray, A: np.ndarray) -> np.ndarray:
    """Re-index a cubic grid ``[G,G,G]`` (axes x, y, z of its frame) into the frame rotated by
    the signed permutation ``A`` [3,3] (``p_new = A p``), about the grid's centre."""
    A = np.rint(np.asarray(A)).astype(int)
    src = [int(np.flatnonzero(A[c])[0]) for c in range(3)]     # new axis c <- old axis src[c]
    out = np.transpose(grid, src)
    flip = tuple(c for c in range(3) if A[c, src[c]] < 0)
    return np.ascontiguousarray(np.flip(out, flip) if flip else out)


def r2n2_cameras(views: list[R2N2View], image_size: int,
                 to_canonical: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Cameras of ``views`` as sc3d stores them: ``K [V,3,3]``, ``R [V,3,3]``, ``t [V,3]``
    (OpenCV, world = canonical frame), ``azimuth``/``elevation`` (sc3d convention, degrees) and
    ``distance`` (canonical units) ``[V]`` read back from the camera centre.

    ``to_canonical``: 4x4 similarity ``p_can = s A p_obj + b`` (uniform scale ``s``, rotation
    ``A``) from the ShapeNet OBJ frame to the canonical frame; identity when ``None``."""
    R, t = r2n2_obj_extrinsics(views)
    if to_canonical is not None:
        M = np.asarray(to_canonical, dtype=np.float64)
        s = np.cbrt(np.linalg.det(M[:3, :3]))
        A = M[:3, :3] / s
        # p_obj = A^T (p_can - b) / s  ->  X_cam ~ R A^T p_can + (s t - R A^T b)
        R = R @ A.T
        t = t * s - R @ M[:3, 3]
    C = -np.einsum("vji,vj->vi", R, t)                                   # centres, canonical
    dist = np.linalg.norm(C, axis=-1)
    az = np.mod(np.rad2deg(np.arctan2(C[:, 0], C[:, 2])), 360.0)
    el = np.rad2deg(np.arcsin(np.clip(C[:, 1] / dist, -1.0, 1.0)))
    K = np.broadcast_to(r2n2_intrinsics(image_size), (len(views), 3, 3)).copy()
    return {"K": K, "R": R, "t": t, "azimuth": az, "elevation": el, "distance": dist}


def check_cameras(cameras: dict, metadata: Path, views: list[R2N2View]) -> None:
    """``ValueError`` naming ``metadata`` and its first view whose camera (``r2n2_cameras``, canonical
    frame) the shards cannot hold (not finite as float32) or that sits inside the voxel grid's cube
    (distance <= sqrt(3)/2, which ``render --distance`` refuses too): an extreme distance ratio."""
    big = float(np.finfo(np.float32).max)
    t, dist = np.asarray(cameras["t"]), np.asarray(cameras["distance"])
    ok = np.isfinite(t).all(-1) & (np.abs(t).max(-1) < big) & np.isfinite(dist) & (dist < big)
    ok &= dist > camera.MIN_DISTANCE
    if not ok.all():
        v = int(np.flatnonzero(~ok)[0])
        raise ValueError(f"{metadata}: view {v} (distance ratio {views[v].distance_ratio:g}) puts the camera "
                         f"{dist[v]:g} from the object's centre in the canonical frame; it must be finite and more "
                         f"than {camera.MIN_DISTANCE:.3f} (sqrt(3)/2, outside the voxel grid's cube)")


# ----------------------------------------------------------------------------- images
def load_rendering(path: Path, image_size: int, background=(255, 255, 255)
                   ) -> tuple[np.ndarray, np.ndarray]:
    """One R2N2 PNG -> ``(rgb [S,S,3] uint8, mask [S,S] uint8)`` at ``image_size``.

    Premultiplied colour and alpha are area-averaged (box filter), the mask is
    ``alpha >= 0.5`` and the colour is composited over ``background``. A PNG without an alpha
    channel raises ``ValueError`` (no mask can be made), and so does one that is not square (the
    cameras are those of a square image)."""
    from PIL import Image

    with Image.open(path) as im:
        if "A" not in im.getbands() and not (im.mode == "P" and "transparency" in im.info):
            raise ValueError(f"{path}: image has no alpha channel ({im.mode}); cannot make a mask")
        if im.width != im.height:  # the cameras (K) are those of a square image: a stretch would move the object
            raise ValueError(f"{path}: image is {im.width}x{im.height}, not square (3D-R2N2's renderings are "
                             "137x137); its camera would not match it")
        rgba = np.asarray(im.convert("RGBA"), dtype=np.float32) / 255.0
    alpha = rgba[..., 3]
    premult = rgba[..., :3] * alpha[..., None]
    size = (image_size, image_size)
    if rgba.shape[:2] != size:
        def box(a: np.ndarray) -> np.ndarray:
            return np.asarray(Image.fromarray(a, mode="F").resize(size, Image.BOX))
        alpha = box(alpha)
        premult = np.stack([box(np.ascontiguousarray(premult[..., c])) for c in range(3)], -1)
    bg = np.asarray(background, dtype=np.float32) / 255.0
    rgb = premult + (1.0 - alpha[..., None]) * bg
    rgb8 = np.clip(np.round(rgb * 255.0), 0, 255).astype(np.uint8)
    return rgb8, (alpha >= MASK_THRESHOLD).astype(np.uint8)


# ----------------------------------------------------------------------------- discovery
@dataclass(frozen=True)
class R2N2Model:
    """One model present in ``ShapeNetRendering`` (``rendering_dir`` = its ``rendering/``)."""

    category: str
    model_id: str
    rendering_dir: Path
    binvox: Path


def find_r2n2_models(renderings: Path, voxels: Path, categories=None
                     ) -> tuple[list[R2N2Model], list[dict]]:
    """Model folders of ``ShapeNetRendering/SYNSET/MODEL_ID`` (sorted by synset, model id),
    paired with ``ShapeNetVox32/SYNSET/MODEL_ID/model.binvox``. Problems: folders without
    ``rendering/``, models without a binvox file, voxel models without renderings. Hidden folders
    (``.ipynb_checkpoints``, name starting with ``.``) are skipped, as ``render`` skips them."""
    renderings, voxels = Path(renderings), Path(voxels)
    for p, what in ((renderings, "--renderings"), (voxels, "--voxels")):
        if not p.is_dir():
            raise FileNotFoundError(f"{p}: {what} folder not found")
    wanted = resolve_categories(categories) if categories is not None else None  # '' names nothing: refused
    problems: list[dict] = []
    models: list[R2N2Model] = []
    synsets = sorted(d.name for d in renderings.iterdir() if d.is_dir() and is_synset_id(d.name))
    if not synsets:
        raise FileNotFoundError(f"{renderings}: no synset folders (8-digit names) found; expected "
                                "ShapeNetRendering/SYNSET/MODEL_ID/rendering/")
    for syn in synsets:
        if wanted is not None and syn not in wanted:
            continue
        seen = set()
        for mdir in sorted(d for d in (renderings / syn).iterdir() if d.is_dir() and not d.name.startswith(".")):
            seen.add(mdir.name)
            rdir = mdir / "rendering"
            bv = voxels / syn / mdir.name / "model.binvox"
            if not rdir.is_dir():
                problems.append({"source": str(mdir), "reason": "model folder without rendering/"})
                continue
            if not bv.is_file():
                problems.append({"source": str(bv), "reason": "missing binvox file for a rendered model"})
                continue
            models.append(R2N2Model(syn, mdir.name, rdir, bv))
        vdir = voxels / syn
        if vdir.is_dir():
            for mdir in sorted(d for d in vdir.iterdir()
                               if d.is_dir() and d.name not in seen and not d.name.startswith(".")):
                problems.append({"source": str(mdir), "reason": "voxel model without renderings; skipped"})
    if wanted is not None:
        for c in sorted(wanted - set(synsets)):
            problems.append({"source": str(renderings), "reason": f"requested category {c!r} not found"})
    return models, problems


def refuse_link_out(path: Path, folder: Path) -> None:
    """``ValueError`` naming ``path`` when it is a symbolic link whose target lies outside
    ``folder`` (as resolved: a model folder that is itself a link, to a dataset on another disk,
    is fine), as ``render`` treats textures and material files linked out of their folder: an
    import reads nothing outside the model's folders. A missing ``path`` passes (the reader
    reports it)."""
    if path.is_symlink() and not path.resolve().is_relative_to(folder.resolve()):
        raise ValueError(f"{path}: a link to {path.resolve()}, outside {folder}; refused (not read)")


def load_r2n2_object(model: R2N2Model, split: str, image_size: int = 64, background=(255, 255, 255),
                     voxel_frame: str = "cube", front: str = R2N2_FRONT):
    """Read one model into a :class:`sc3d_data.io.shards.ObjectRecord` (cameras, voxels and
    ``to_canonical`` in the canonical frame, module doc), images resized to ``image_size`` over
    ``background`` (R, G, B 0-255); ``voxel_frame`` and ``front`` as in the module doc.
    ``ValueError`` naming the file and the problem on bad input (metadata, PNGs, binvox)."""
    from sc3d_data.io.binvox import read_binvox
    from sc3d_data.io.shards import ObjectRecord, border_clipped

    for f in (model.rendering_dir / "rendering_metadata.txt", model.rendering_dir / "renderings.txt", model.binvox):
        refuse_link_out(f, f.parent)
    views = read_rendering_metadata(model.rendering_dir / "rendering_metadata.txt")
    names = read_rendering_list(model.rendering_dir)
    vox = read_binvox(model.binvox)
    grid = np.asarray(vox.voxels)
    if grid.shape != (R2N2_VOXEL_RESOLUTION,) * 3:
        raise ValueError(f"{model.binvox}: voxel grid {'x'.join(map(str, grid.shape))}, "
                         f"expected {R2N2_VOXEL_RESOLUTION}^3")
    centre, size = grid_placement(vox.translate, vox.scale, voxel_frame)
    to_canonical = obj_to_canonical(centre, size, front)
    grid = rotate_grid(grid, canonical_rotation("+Y", front))
    S = image_size
    images = np.empty((len(views), S, S, 3), dtype=np.uint8)
    masks = np.empty((len(views), S, S), dtype=np.uint8)
    for v, name in enumerate(names):
        png = model.rendering_dir / name
        refuse_link_out(png, model.rendering_dir)
        if not png.is_file():
            raise ValueError(f"{png}: missing rendering (view {v})")
        try:
            images[v], masks[v] = load_rendering(png, S, background)
        except ValueError:
            raise
        except Exception as e:  # PIL's errors on truncated / non-image files
            raise ValueError(f"{png}: cannot read image ({type(e).__name__}: {e})") from None
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # checked next, in one line
        arrays = r2n2_cameras(views, S, to_canonical)
    check_cameras(arrays, model.rendering_dir / "rendering_metadata.txt", views)
    arrays.update({"images": images, "masks": masks, "clipped": border_clipped(masks),
                   "to_canonical": to_canonical, "voxels": grid.astype(np.uint8)})
    return ObjectRecord(model_id=model.model_id, category=model.category, split=split,
                        source=str(model.rendering_dir.parent), arrays=arrays)
