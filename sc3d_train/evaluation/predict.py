"""``sc3d-train predict``: images -> voxels, mesh, pose and a picture, with a trained checkpoint.

Per input image ``NAME.png`` (written to the output directory):

* ``NAME.binvox``: occupancy ``>= threshold`` (sc3d's [-0.5, 0.5]^3 cube, ``sc3d_data.io.binvox``),
* ``NAME.npz``: ``probabilities`` float32 [G,G,G] ([x,y,z]), ``voxels`` bool, ``mask`` float32
  [S,S] (predicted mask probability), ``azimuth``, ``elevation`` (degrees), ``threshold``,
* ``NAME.obj``: marching-cubes surface (scikit-image) of the probabilities at ``threshold``, in
  the canonical frame (the grid cube [-0.5, 0.5]^3, +Y up, front +Z),
* ``NAME.json``: the predicted pose (azimuth, elevation in degrees; the camera distance of the
  training data), the image's path as given and its real path, and the absolute paths above,
* ``NAME.png``: the input, the predicted mask, and the predicted voxels' silhouette seen from the
  predicted pose (``sc3d_data.geometry.projection`` through ``sc3d_data.geometry.camera``).

Input images must have the training image size (no silent resizing: the camera intrinsics and
the framing of the training renders would no longer hold). Modes: RGB is used as is; RGBA, LA,
L and P, and RGB with a transparent colour (a PNG's tRNS key), are converted to RGBA and
alpha-composited onto the training data's background colour (stored in the checkpoint), so a
transparent PNG looks like the renders; other modes (CMYK,
16-bit grey, float, 1-bit) are refused. A 16-bit RGB(A) PNG is read by PIL as 8-bit RGB(A)
(its high bytes), which is the image as viewers show it. A JPEG that holds further images after
its own (MPO: a camera's preview or depth image) is read as its first image, which viewers show. An EXIF orientation tag (a camera's JPEG) is applied, so the
image is used as viewers show it; an animated image (several frames) is refused.

A checkpoint whose weights are not finite (a diverged run, a damaged file), or whose prediction of
an input is not (NaN, inf), is refused in one line before any output is written.
"""
from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np
import torch

from sc3d_data.io.pictures import write_figure
from sc3d_data.io.shards import atomic_write_bytes
from sc3d_train.loop.checkpoint import run_checkpoint
from sc3d_train.loop.checkpoint_model import load_model
from sc3d_train.evaluation.prediction_files import (ImageError, check_default_folder_free, check_inputs_kept,
                                                    check_outputs_replaceable, check_same_images, output_files,
                                                    recorded_files)
from sc3d_train.settings.command_config import PredictConfig, check_pose_source

ACCEPTED_MODES = ("RGB", "RGBA", "LA", "L", "P")


def load_image(path: Path, image_size: int, background: list[int]) -> np.ndarray:
    """``path`` -> float32 ``[S, S, 3]`` in [0, 1] (see module doc for modes and sizes)."""
    import warnings

    from PIL import Image, ImageOps

    from sc3d_data.io.names import printable

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            img = Image.open(path)  # reads the header only
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as e:
        raise ImageError(f"{printable(path)}: image too large to open ({e})") from e
    except Exception as e:  # noqa: BLE001 - any decoder error: the file is not a usable image
        raise ImageError(f"{printable(path)}: cannot read image ({type(e).__name__}: {e})") from e
    if img.size != (image_size, image_size):  # before decoding: an oversized image is never decoded
        raise ImageError(f"{printable(path)}: image is {img.size[0]}x{img.size[1]}, the model expects "
                         f"{image_size}x{image_size} (crop/resize it like the training renders)")
    frames = getattr(img, "n_frames", 1) if img.format != "MPO" else 1  # MPO: a JPEG and its preview or depth
    # image, the first of them the photo that viewers show (PIL reads it unless told to seek)
    if frames > 1:  # which frame is the view is not ours to guess
        raise ImageError(f"{printable(path)}: an animated image of {frames} frames; give one frame as a still image")
    try:
        img.load()
        img = ImageOps.exif_transpose(img)  # as viewers show it: a camera's orientation tag turns the pixels
    except Exception as e:  # noqa: BLE001 - truncated or corrupt pixel data, a broken EXIF block
        raise ImageError(f"{printable(path)}: cannot read image ({type(e).__name__}: {e})") from e
    if img.mode not in ACCEPTED_MODES:
        raise ImageError(f"{printable(path)}: image mode {img.mode!r} not supported (use one of {ACCEPTED_MODES})")
    if img.mode == "RGB" and "transparency" not in img.info:  # an RGB PNG's tRNS colour key (a cut-out
        # as PNG optimisers store it) is transparency too: composited below, as viewers show it
        return np.asarray(img, dtype=np.float32) / 255.0
    rgba = np.asarray(img.convert("RGBA"), dtype=np.float32) / 255.0
    alpha = rgba[..., 3:4]
    bg = np.asarray(background, dtype=np.float32)[None, None, :3] / 255.0
    return rgba[..., :3] * alpha + bg * (1.0 - alpha)


def voxel_mesh(probabilities: np.ndarray, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """Marching cubes of ``probabilities [G,G,G]`` ([x,y,z]) at ``threshold``: ``(vertices [V,3]``
    in the canonical frame, within the grid's cube [-0.5, 0.5]^3, ``faces [F,3])``. The grid is
    zero-padded so the surface is closed; voxel centres sit at ``-0.5 + (i + 0.5)/G`` (SPEC). Empty arrays when nothing is occupied."""
    from skimage.measure import marching_cubes

    from sc3d_data.geometry.voxel_grid import voxel_centres

    G = probabilities.shape[0]
    if threshold <= 0.0:  # every voxel is occupied (p >= 0), also those whose probability underflowed
        # to exactly 0.0, which marching cubes at level 0 cannot tell from the zero padding: the cube
        probabilities, threshold = np.ones_like(probabilities), 0.5
    padded = np.pad(probabilities.astype(np.float32), 1)
    top = float(padded.max())
    if top < threshold or top <= 0.0:  # all zero: no level separates the grid from its zero padding
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    level = float(threshold)
    if top == level:  # occupied voxels exactly at the threshold (a probability saturated at 1.0 with
        # threshold 1): marching cubes finds no surface at the grid's maximum, so take the float32 just below
        level = float(np.nextafter(np.float32(level), np.float32(0.0)))
    verts, faces, _, _ = marching_cubes(padded, level=level)
    verts = voxel_centres(verts - 1, G)  # undo the padding: vertex coordinates are voxel indices
    # a level below half the probability of a voxel on the grid's border puts the surface between
    # its centre and the padding's, outside the grid (at threshold 0 on the padding itself, half a
    # voxel out): the surface ends at the grid's faces, as its voxels do
    np.clip(verts, -0.5, 0.5, out=verts)
    # skimage's faces wind inwards for a solid of high values (negative signed volume): flip
    return verts, faces[:, ::-1].copy()


def write_obj(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """The mesh as a Wavefront OBJ (vertices in the canonical frame, faces 1-based), written whole
    or not at all (``atomic_write_bytes``)."""
    lines = ["# sc3d-train predict: marching cubes of the predicted occupancy\n"]
    if len(faces) == 0:
        lines.append("# empty prediction: no voxel reached the threshold\n")
    lines += [f"v {x:.5f} {y:.5f} {z:.5f}\n" for x, y, z in vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces]
    atomic_write_bytes(path, "".join(lines).encode())


def plot_prediction(path: Path, image: np.ndarray, mask: np.ndarray, silhouette: np.ndarray,
                    azimuth: float, elevation: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(7.5, 2.8))
    for ax, img, title in zip(axes, (image, mask, silhouette),
                              ("input", "predicted mask", f"voxels at az {azimuth:.0f}, el {elevation:.0f}")):
        ax.imshow(img, cmap=None if img.ndim == 3 else "gray", vmin=0, vmax=1)
        ax.set_title(title, fontsize=8)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    write_figure(fig, path, dpi=90)
    plt.close(fig)


@torch.no_grad()
def predict(checkpoint: Path, images: list[Path], out: Path | None, device: str = PredictConfig.device,
            threshold: float = PredictConfig.threshold, pose_from: str = PredictConfig.pose_from,
            pick: str = PredictConfig.pick) -> list[dict]:
    """Predict every image (all are checked before the model runs) with ``checkpoint`` (a file,
    or a run folder: its ``pick`` checkpoint, :func:`~sc3d_train.loop.checkpoint.run_checkpoint`);
    a checkpoint whose weights, or prediction of an image, are not finite (NaN, inf) is refused
    (``CheckpointError``) before anything is written; returns one dict per image (the content of
    its JSON file). ``pose_from``: ``"search"`` (the default of every entry point,
    :data:`~sc3d_train.settings.command_config.DEFAULT_POSE_SOURCE`) or ``"head"``, as in ``eval``.
    An image file given more than once (by any path) is predicted once, under its first path.
    ``out`` None: ``RUN_DIR/predictions`` beside the checkpoint, which is never given to the
    prediction of an image of the same name by another checkpoint file or ``pose_from``
    (:func:`check_default_folder_free`)."""
    from sc3d_data.io.binvox import write_binvox
    from sc3d_data.io.outlock import exclusive_lock
    from sc3d_data.io.shards import write_json_atomic
    from sc3d_data.io.names import printable
    from sc3d_train.evaluation.evaluate import default_output_dir, require_finite_weights, voxel_silhouette
    from sc3d_train.loop.checkpoint import CheckpointError

    check_pose_source(pose_from)
    if not images:
        raise ImageError("no input images given")
    firsts: dict[str, Path] = {}  # a file given twice (by any path): once, under its first path
    for image in images:
        firsts.setdefault(os.path.realpath(image), image)
    images = list(firsts.values())
    if not 0.0 <= threshold <= 1.0:  # also NaN
        raise ValueError(f"--threshold must be an occupancy probability in [0, 1], got {threshold}")
    from sc3d_train.loop.runtime import resolve_device

    checkpoint = run_checkpoint(checkpoint, pick)
    default_out = out is None
    out = default_output_dir(checkpoint, "predictions") if default_out else Path(out)
    with exclusive_lock(out, "sc3d-train predict", create=True):  # one predict writes here at a time
        outputs = output_files(images, out)
        check_inputs_kept(images, outputs, out)
        if default_out:
            check_default_folder_free(outputs, checkpoint, pose_from, out)
        check_same_images(images, outputs, out)
        check_outputs_replaceable(outputs, out)
        dev = resolve_device(device)
        model, cfg, _ = load_model(checkpoint, dev)
        require_finite_weights(checkpoint, model)
        size = cfg.model.image_size
        arrays = [load_image(Path(p), size, cfg.background) for p in images]
        K = np.asarray(cfg.intrinsics if cfg.intrinsics is not None else _default_K(size), dtype=np.float64)
        # every prediction first, so that one that is not finite is refused before anything is written
        predictions = [predict_one(model, cfg, arr, K, dev, pose_from) for arr in arrays]
        for path, (probs, mask, az, el) in zip(images, predictions):
            if not (np.isfinite(probs).all() and np.isfinite(mask).all() and np.isfinite([az, el]).all()):
                raise CheckpointError(f"{checkpoint}: its prediction for {printable(path)} is not finite (NaN or inf "
                                      "voxels, mask or pose) although its weights are: the network overflows on this "
                                      "input; nothing written")
        results = []
        for path, arr, files, (probs, mask, az, el) in zip(images, arrays, outputs, predictions):
            voxels = probs >= threshold
            info = {"image": str(path), "image_realpath": os.path.realpath(path), "checkpoint": os.path.abspath(checkpoint), "azimuth_deg": az, "elevation_deg": el, "pose_from": pose_from,
                    "camera_distance": cfg.camera_distance, "threshold": threshold,
                    "occupied_voxels": int(voxels.sum()), "files": recorded_files(files)}
            # the listing first (whole or not at all): a run stopped before the image's other files
            # are written leaves them listed, so running it again may replace them
            write_json_atomic(files["json"], info)
            write_binvox(files["binvox"], voxels)
            npz = io.BytesIO()
            np.savez_compressed(npz, probabilities=probs.astype(np.float32), voxels=voxels,
                                mask=mask.astype(np.float32), azimuth=az, elevation=el, threshold=threshold)
            atomic_write_bytes(files["npz"], npz.getvalue())
            write_obj(files["obj"], *voxel_mesh(probs, threshold))
            sil = voxel_silhouette(voxels, az, el, cfg.camera_distance, K, size)
            plot_prediction(files["png"], arr, mask, sil, az, el)
            results.append(info)
        return results


@torch.no_grad()
def predict_one(model, cfg, image: np.ndarray, K: np.ndarray, dev, pose_from: str) -> tuple:
    """``(probabilities [G,G,G], mask [S,S], azimuth, elevation)`` of ``model`` (run config ``cfg``)
    for ``image`` ``[S,S,3]``; the pose is the self-consistent one for ``pose_from="search"``, as in
    ``eval``, else the pose head's."""
    x = torch.from_numpy(image.transpose(2, 0, 1).copy())[None].to(dev)
    res = model(x)
    if pose_from == "search":  # test-time self-consistency, as in `eval`
        from sc3d_train.paper.pose_search import self_consistent_pose

        res.azimuth, res.elevation = self_consistent_pose(
            res, torch.as_tensor(K, dtype=torch.float32, device=dev)[None],
            torch.tensor([float(cfg.camera_distance)], device=dev), model.pose_grid,
            cfg.loss_weights)
    probs = torch.sigmoid(res.voxel_logits.float())[0].cpu().numpy()
    mask = torch.sigmoid(res.mask_logits.float())[0].cpu().numpy()
    return probs, mask, float(res.azimuth[0]), float(res.elevation[0])


def _default_K(size: int) -> np.ndarray:
    from sc3d_data.geometry.camera import intrinsics

    return intrinsics(size)
