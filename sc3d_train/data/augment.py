"""Augmentation of the input images of training that keeps the camera and every label true
(``fit --augment``; issue 24 item 2).

Only the pixel values of ``images`` change: no pixel moves (no flip, crop, scale or rotation,
which would change the camera ``K``, ``R``, ``t`` that the self-consistency module and the pose
head rely on), and the voxels, masks, pose targets and cameras of the batch are untouched.

Conventions
    ``images [B, 3, H, W]`` float32 RGB in [0, 1] (the float training batch of
    ``sc3d_train.data.batch_format.expand_batch``); ``foreground [B, H, W]`` float or bool, 1 (True) on
    the object's pixels and 0 on the background's. Every function returns a new tensor of the
    images' shape, dtype and device, with values in [0, 1].
What each image gets (parameters drawn per image, uniform in the ranges of :data:`RANGES`)
    * object pixels (foreground 1): :func:`jitter_colour`, a function of the pixel's own value
      and the image's parameters only: brightness (x b), contrast (about the image's mean grey
      level, x c), saturation (grey + s (x - grey)), a hue-like rotation of the colour about the
      grey axis (angle h), then lighting-like shading: a linear ramp 1 + a (u cos phi + v sin phi)
      across the image (u, v in [-1, 1] at the pixel's centre), i.e. light from one side;
    * background pixels (foreground 0), :func:`draw_background`: with probability
      ``keep_background`` the image keeps its own background (the renders' white, which is what
      eval and predict images show), otherwise a linear gradient between two random colours along
      a random direction (a solid colour when the two are near) plus Gaussian noise of a random
      standard deviation, so that the encoder cannot learn "white = background".
Default
    Off (``RunConfig.augment``): at the CPU preset on the 195-mesh pool it left held-out IoU@0.4
    within one seed's noise (0.359 against 0.351/0.355) and cost pose accuracy and mask IoU on
    the white-background test images (docs/training.md, "Measured: input augmentation").
Randomness
    A private ``torch.Generator`` on the images' device (:func:`augment_generator`), seeded from
    the run's seed, the optimiser step, the rank and the batch's slot in the step: the same step
    draws the same numbers whatever ran before, so ``--resume`` stays exact and the global RNG
    (reparameterisation noise) is never touched. The draws are made on the device with fixed
    shapes, and every constant is made there too (no host-to-device copy, which would wait for
    the device; no host read), so the step stays free of host syncs.
"""
from __future__ import annotations

import math

import numpy as np
import torch

__all__ = ["RANGES", "augment_generator", "augment_images", "draw_background", "draw_params", "jitter_colour",
           "key_foreground"]

#: uniform ranges of the per-image parameters (brightness, contrast and saturation factors, hue
#: angle in turns, shading slope a, background noise standard deviation) and the probability
#: that an image keeps its own background
RANGES = {"brightness": (0.7, 1.3), "contrast": (0.7, 1.3), "saturation": (0.6, 1.4), "hue": (-0.05, 0.05),
          "shading": (0.0, 0.3), "noise": (0.0, 0.04)}
KEEP_BACKGROUND = 0.2
#: weights of the grey level (ITU-R BT.601 luma, as torchvision's rgb_to_grayscale)
LUMA = (0.299, 0.587, 0.114)


def key_foreground(images: torch.Tensor, background_rgb) -> torch.Tensor:
    """``[B, H, W]`` bool: the pixels of ``images [B, 3, H, W]`` (uint8 values / 255) whose
    colour differs from ``background_rgb`` (3 ints 0-255, the shards' background): the object's
    pixels found from the image alone (a colour key), for images whose masks are labels that
    training may not read (the unlabelled images of ``semi``). On sc3d renders (no
    anti-aliasing) this equals the stored mask wherever no object pixel has exactly the
    background's colour."""
    values = (images * 255.0).round()
    r, g, b = (float(c) for c in background_rgb)
    return (values[:, 0] != r) | (values[:, 1] != g) | (values[:, 2] != b)


def augment_generator(seed: int, step: int, rank: int = 0, slot: int = 0,
                      device: torch.device | str = "cpu") -> torch.Generator:
    """A generator on ``device`` seeded from ``(seed, step, rank, slot)`` (numpy's SeedSequence
    mixes them: neighbouring steps get unrelated streams)."""
    state = np.random.SeedSequence([int(seed), int(step), int(rank), int(slot), 0x5C3DA6]).generate_state(2)
    g = torch.Generator(device=device)
    g.manual_seed(int(state[0]) << 32 | int(state[1]))
    return g


def draw_params(batch: int, generator: torch.Generator, device: torch.device | str = "cpu") -> dict:
    """The per-image parameters of one batch: each key of :data:`RANGES` and ``phi`` (shading
    direction, radians) as ``[B]`` float32; ``colours [B, 2, 3]`` (the background gradient's
    ends), ``theta [B]`` (its direction), ``keep [B]`` bool (keep the own background). Drawn in a
    fixed order with fixed shapes."""
    u = torch.rand(batch, 9, generator=generator, device=device)
    p = {k: lo + (hi - lo) * u[:, i] for i, (k, (lo, hi)) in enumerate(RANGES.items())}
    p["phi"] = 2 * math.pi * u[:, 6]
    p["theta"] = 2 * math.pi * u[:, 7]
    p["keep"] = u[:, 8] < KEEP_BACKGROUND
    p["colours"] = torch.rand(batch, 2, 3, generator=generator, device=device)
    return p


def _luma(x: torch.Tensor) -> torch.Tensor:
    """Grey level ``[B, 1, H, W]`` of ``x [B, 3, H, W]``."""
    return x[:, 0:1] * LUMA[0] + x[:, 1:2] * LUMA[1] + x[:, 2:3] * LUMA[2]


def _ramp(batch_angle: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """``u cos(angle) + v sin(angle)`` ``[B, 1, H, W]`` with ``u`` (columns) and ``v`` (rows) the
    pixel centres mapped to [-1, 1]."""
    dev = batch_angle.device
    u = (torch.arange(w, device=dev, dtype=torch.float32) + 0.5) * (2.0 / w) - 1.0
    v = (torch.arange(h, device=dev, dtype=torch.float32) + 0.5) * (2.0 / h) - 1.0
    c, s = torch.cos(batch_angle).view(-1, 1, 1, 1), torch.sin(batch_angle).view(-1, 1, 1, 1)
    return c * u.view(1, 1, 1, w) + s * v.view(1, 1, h, 1)


def _hue_rotation(angle_turns: torch.Tensor) -> torch.Tensor:
    """``[B, 3, 3]`` rotations of RGB space about the grey axis (1, 1, 1) by ``angle_turns``
    (Rodrigues' formula): greys stay grey and the channel mean is kept."""
    a = 2 * math.pi * angle_turns
    c, s = torch.cos(a).view(-1, 1, 1), torch.sin(a).view(-1, 1, 1)
    eye = torch.eye(3, device=a.device, dtype=torch.float32)
    # the cross-product matrix of the unit grey axis: [[0, -1, 1], [1, 0, -1], [-1, 1, 0]] / sqrt(3)
    k = (torch.roll(eye, 1, dims=0) - torch.roll(eye, -1, dims=0)) / math.sqrt(3.0)
    return eye + s * k + (1 - c) * (k @ k)


def jitter_colour(images: torch.Tensor, params: dict, foreground: torch.Tensor) -> torch.Tensor:
    """Brightness, contrast, saturation, hue-like rotation and shading (module doc) of every
    pixel of ``images [B, 3, H, W]`` in [0, 1]; the result is clamped to [0, 1]. Each pixel's
    value depends on its own value, its position (shading) and the image's parameters, and on
    the mean grey level of the image's object pixels (``foreground [B, H, W]``; the contrast
    pivot), nothing else. Identity at brightness, contrast and saturation 1, hue and shading 0."""
    b = images.shape[0]
    x = images * params["brightness"].view(b, 1, 1, 1)
    fg = foreground.to(x.dtype).unsqueeze(1)
    mean = (_luma(x) * fg).sum(dim=(2, 3), keepdim=True) / fg.sum(dim=(2, 3), keepdim=True).clamp_min(1.0)
    x = (x - mean) * params["contrast"].view(b, 1, 1, 1) + mean
    grey = _luma(x)
    x = grey + params["saturation"].view(b, 1, 1, 1) * (x - grey)
    x = torch.einsum("bij,bjhw->bihw", _hue_rotation(params["hue"]), x)
    h, w = images.shape[-2:]
    x = x * (1.0 + params["shading"].view(b, 1, 1, 1) * _ramp(params["phi"], h, w))
    return x.clamp(0.0, 1.0)


def draw_background(images: torch.Tensor, params: dict, generator: torch.Generator) -> torch.Tensor:
    """A new background ``[B, 3, H, W]`` in [0, 1] for each image of ``images`` (only its shape,
    device and dtype are read): a gradient from ``colours[:, 0]`` to ``colours[:, 1]`` along
    direction ``theta`` plus Gaussian noise of standard deviation ``noise``."""
    b, _, h, w = images.shape
    t = 0.5 * (_ramp(params["theta"], h, w) / math.sqrt(2.0) + 1.0)  # [B, 1, H, W] in [0, 1]
    c0, c1 = params["colours"][:, 0].view(b, 3, 1, 1), params["colours"][:, 1].view(b, 3, 1, 1)
    noise = torch.randn(images.shape, generator=generator, device=images.device, dtype=images.dtype)
    return (c0 + (c1 - c0) * t + params["noise"].view(b, 1, 1, 1) * noise).clamp(0.0, 1.0)


def augment_images(images: torch.Tensor, foreground: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
    """``images [B, 3, H, W]`` in [0, 1] with the object's pixels (``foreground [B, H, W]`` 1 or
    True) colour-jittered (:func:`jitter_colour`) and the background's (0 or False) replaced by
    :func:`draw_background` (kept as they are for images drawn with ``keep``). Parameters come
    from ``generator`` (on the images' device). The output has the images' memory format."""
    params = draw_params(images.shape[0], generator, images.device)
    background = draw_background(images, params, generator)
    background = torch.where(params["keep"].view(-1, 1, 1, 1), images, background)
    fg = foreground.to(torch.bool)
    out = torch.where(fg.unsqueeze(1), jitter_colour(images, params, fg), background)
    if images.is_contiguous(memory_format=torch.channels_last) and not images.is_contiguous():
        out = out.contiguous(memory_format=torch.channels_last)
    return out
