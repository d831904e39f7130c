"""The batch format of training: the 48 px self-consistency masks, the compact batch the loader
yields (uint8 images, bool masks, uint8 voxels: 1 byte per value) and its expansion to the
float training batch on the training device (keys: ``sc3d_train.data.dataset``).

Masks for the self-consistency module (48x48 by default) are the exact area average of the
64x64 rendered mask (each output pixel covers 4/3 x 4/3 input pixels under the pixel-edge
convention of ``sc3d_data.geometry.camera``; ``self_consistency.area_downsample``), thresholded
at >= 0.5; their ``K`` is scaled with ``sc3d_data.geometry.camera.scale_intrinsics``, which
keeps the principal point at the image centre.
"""
from __future__ import annotations

import functools

import numpy as np
import torch

from sc3d_train.paper.self_consistency import area_downsample


def sc_masks(masks: np.ndarray, mask_size: int) -> torch.Tensor:
    """Self-consistency masks ``[V, M, M]`` float {0, 1} of rendered masks ``[V, S, S]``: exact
    area average (``sc3d_train.paper.self_consistency.area_downsample``) thresholded at >= 0.5. Their
    camera is ``scale_intrinsics(K, M, S)``. The area average is separable and linear, so it is
    computed as ``W m W^T`` with the ``[M, S]`` weights ``W`` taken from ``area_downsample``
    itself (:func:`area_weights`): 5x cheaper than upsampling to the common multiple."""
    return torch.from_numpy(sc_masks_bool(masks, mask_size).astype(np.float32))


def sc_masks_bool(masks: np.ndarray, mask_size: int) -> np.ndarray:
    """:func:`sc_masks` as a numpy bool array ``[V, M, M]``; ``S = 4k`` to ``M = 3k`` (64 to 48
    px, the default) in exact integer arithmetic (:func:`_sc_masks_4_to_3`, 1.7x faster)."""
    m = np.asarray(masks) > 0
    if m.shape[-1] % 4 == 0 and 4 * mask_size == 3 * m.shape[-1]:
        return _sc_masks_4_to_3(m)
    w = area_weights(m.shape[-1], mask_size)
    return w @ m.astype(np.float32) @ w.T >= np.float32(0.5 - 1e-6)


def _sc_masks_4_to_3(m: np.ndarray) -> np.ndarray:
    """The 4 -> 3 area average of bool masks ``[..., 4k, 4k]`` thresholded at 0.5, as integers:
    output pixels 0, 1, 2 of each block of 4 input pixels cover them by (1, 1/3), (2/3, 2/3) and
    (1/3, 1) of their 4/3-pixel width, i.e. weights (3, 1, 0, 0), (0, 2, 2, 0), (0, 0, 1, 3) / 4;
    applied to rows then columns, the average is ``sum / 16`` and ``>= 0.5`` is ``sum >= 8``."""
    def quarters(q: np.ndarray, axis: int) -> np.ndarray:  # q [..., 4, ...] (the 4 at ``axis``)
        part = [np.take(q, i, axis=axis) for i in range(4)]
        return np.stack([3 * part[0] + part[1], 2 * (part[1] + part[2]), part[2] + 3 * part[3]], axis=axis)

    u = m.view(np.uint8)
    *lead, s, _ = u.shape
    rows = quarters(u.reshape(*lead, s // 4, 4, s), -2).reshape(*lead, -1, s)        # [..., 3k, 4k]
    return quarters(rows.reshape(*lead, rows.shape[-2], s // 4, 4), -1).reshape(*lead, rows.shape[-2], -1) >= 8


@functools.lru_cache(maxsize=8)
def area_weights(size: int, mask_size: int) -> np.ndarray:
    """``W [M, S]`` float32 with ``area_downsample(m, M) == W m W^T`` for ``m [S, S]``: column
    ``j`` is ``area_downsample`` of the image whose row ``j`` is 1 (its rows average to 1)."""
    rows = torch.zeros(size, size, size)
    rows[torch.arange(size), torch.arange(size), :] = 1.0
    return area_downsample(rows, mask_size)[:, :, 0].T.contiguous().numpy()


#: arrays of a compact batch that are 0/1 and travel bit-packed between processes
BINARY_KEYS = ("masks", "masks_sc", "voxels")


def _to_float(v: torch.Tensor, scale: float | None = None) -> torch.Tensor:
    """``v`` as a new contiguous float32 tensor on its device, divided by ``scale`` (IEEE
    division, correctly rounded; the divisor is made on the device, not copied from the host). On the CPU with numpy (one thread: torch's intra-op threads
    made this 10x slower on a loaded 2-core machine); elsewhere with torch, dividing by a 0-dim
    device tensor (CUDA computes ``x / python_scalar`` as ``x * (1 / scalar)``)."""
    out = torch.empty(tuple(v.shape), dtype=torch.float32, device=v.device)
    if v.device.type == "cpu":
        if scale is None:
            out.numpy()[...] = v.numpy()
        else:
            np.divide(v.numpy(), np.float32(scale), out=out.numpy(), dtype=np.float32)
        return out
    out.copy_(v)
    return out if scale is None else out.div_(torch.full((), scale, dtype=torch.float32, device=v.device))


def compact_tensors(arrays: dict[str, np.ndarray], strings: dict) -> dict:
    """A compact batch (``ShardDataset.compact_batch``) as the loader yields it: the arrays as
    tensors in their compact dtypes (no copy), the strings as lists. :func:`expand_batch`
    makes the training batch of it."""
    batch = {k: torch.from_numpy(np.ascontiguousarray(a)) for k, a in arrays.items()}
    batch.update({k: list(v) for k, v in strings.items()})
    return batch


def expand_batch(batch: dict, device: torch.device | str | None = None,
                 non_blocking: bool = False) -> dict:
    """The training batch (module docstring) of a compact batch (:func:`compact_tensors`),
    on ``device`` (default: where it is): tensors are moved first, then ``images`` uint8
    [B,S,S,3] become float [B,3,S,S] (NCHW) / 255 and the 0/1 ``masks``, ``masks_sc``,
    ``voxels`` float, so the host sends 1 byte per value instead of 4 and the device does the
    conversion. Values are bit-identical on every device (:func:`_to_float`). Float tensors
    pass unchanged, so expanding twice is harmless."""
    out = {}
    for k, v in batch.items():
        if not torch.is_tensor(v):
            out[k] = v
            continue
        v = v.to(device, non_blocking=non_blocking) if device is not None else v
        if k == "images" and v.dtype == torch.uint8:
            v = _to_float(v.permute(0, 3, 1, 2), scale=255.0)
        elif k in BINARY_KEYS and v.dtype in (torch.bool, torch.uint8):
            v = _to_float(v)
        out[k] = v
    return out
