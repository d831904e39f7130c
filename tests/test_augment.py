"""``fit --augment`` (sc3d_train/augment.py): the object's pixels get only a colour transform of
themselves, the background's only the background draw, the labels and cameras stay bit for bit,
the draws follow (seed, step), and validation, eval and predict see the shards' images as they
are. The exact resume of an augmented run is in tests/test_train.py (the semi resume test)."""
from __future__ import annotations

import math

import h5py
import numpy as np
import torch

from sc3d_cli.train import main
from sc3d_train.data.augment import (augment_generator, augment_images, draw_params, jitter_colour,
                                key_foreground)
from tests.conftest import run_cli
from tests.test_train import TINY, read_csv


def blobs(batch: int = 6, size: int = 32, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """Images ``[B, 3, S, S]`` of uint8 values / 255 and bool masks ``[B, S, S]``: a disc of random
    centre and radius per image (some images all background)."""
    rng = np.random.default_rng(seed)
    images = torch.from_numpy(rng.integers(0, 256, (batch, 3, size, size)).astype(np.float32) / 255)
    yy, xx = np.mgrid[:size, :size]
    masks = np.stack([(yy - rng.uniform(0, size)) ** 2 + (xx - rng.uniform(0, size)) ** 2 < rng.uniform(0, size / 2) ** 2
                      for _ in range(batch)])
    masks[0] = False
    return images, torch.from_numpy(masks)


def identity_params(batch: int, **changes) -> dict:
    p = {"brightness": 1.0, "contrast": 1.0, "saturation": 1.0, "hue": 0.0, "shading": 0.0, "phi": 0.0}
    p.update(changes)
    return {k: torch.full((batch,), float(v)) for k, v in p.items()}


def test_colour_transform_by_hand():
    """The colour jitter against values worked out by hand: identity parameters leave the image;
    brightness b multiplies (clamped at 1); a hue rotation of 1/3 turn about the grey axis maps
    (r, g, b) to (b, r, g); saturation 0 gives the grey level 0.299 r + 0.587 g + 0.114 b; shading
    slope a along +u scales column j of an S-pixel image by 1 + a ((j + 0.5) 2 / S - 1)."""
    images, masks = blobs()
    fg = torch.ones_like(masks)
    torch.testing.assert_close(jitter_colour(images, identity_params(6), fg), images, atol=1e-6, rtol=0)
    torch.testing.assert_close(jitter_colour(images, identity_params(6, brightness=1.5), fg),
                               (images * 1.5).clamp(max=1.0), atol=1e-6, rtol=0)
    torch.testing.assert_close(jitter_colour(images, identity_params(6, hue=1 / 3), fg),
                               images[:, [2, 0, 1]], atol=1e-5, rtol=0)
    grey = 0.299 * images[:, 0] + 0.587 * images[:, 1] + 0.114 * images[:, 2]
    torch.testing.assert_close(jitter_colour(images, identity_params(6, saturation=0.0), fg),
                               grey.unsqueeze(1).expand(-1, 3, -1, -1), atol=1e-6, rtol=0)
    half = torch.full((1, 3, 4, 4), 0.5)
    out = jitter_colour(half, identity_params(1, shading=0.2), torch.ones(1, 4, 4, dtype=torch.bool))
    for j, u in enumerate((-0.75, -0.25, 0.25, 0.75)):
        assert torch.allclose(out[0, :, :, j], torch.tensor(0.5 * (1 + 0.2 * u)), atol=1e-6)
    # contrast pivots on the mean grey level of the object's pixels only: a 2-pixel object of greys
    # 0.2 and 0.6 (mean 0.4) at contrast 2 becomes 0.0 and 0.8 whatever the background holds
    img = torch.ones(1, 3, 2, 2)
    img[0, :, 0, 0], img[0, :, 0, 1] = 0.2, 0.6
    obj = torch.tensor([[[True, True], [False, False]]])
    out = jitter_colour(img, identity_params(1, contrast=2.0), obj)
    assert torch.allclose(out[0, :, 0, 0], torch.tensor(0.0), atol=1e-6)
    assert torch.allclose(out[0, :, 0, 1], torch.tensor(0.8), atol=1e-6)


def test_object_and_background_pixels_come_from_their_own_sources():
    """Changing the background pixels of the input changes no object pixel of the output, and
    (for images that do not keep their background) no background pixel either; changing the
    object pixels changes no background pixel; images that keep their background show the
    input's background exactly. Object pixels equal the colour jitter of the same pixels."""
    images, masks = blobs(batch=16)
    other_bg = torch.where(masks.unsqueeze(1), images, torch.rand(images.shape))
    other_fg = torch.where(masks.unsqueeze(1), torch.rand(images.shape), images)
    out, out_bg, out_fg = (augment_images(x, masks, augment_generator(3, 11)) for x in (images, other_bg, other_fg))
    keep = draw_params(16, augment_generator(3, 11))["keep"]
    assert 0 < int(keep.sum()) < 16, "the seed should give both kinds of image"
    fg, bg = masks.unsqueeze(1).expand_as(images), ~masks.unsqueeze(1).expand_as(images)
    assert torch.equal(out[fg], out_bg[fg])
    drawn = bg & ~keep.view(-1, 1, 1, 1)
    kept = bg & keep.view(-1, 1, 1, 1)
    assert torch.equal(out[drawn], out_bg[drawn]) and torch.equal(out[drawn], out_fg[drawn])
    assert torch.equal(out[kept], images[kept]) and torch.equal(out_bg[kept], other_bg[kept])
    assert not torch.equal(out[drawn], images[drawn])  # the background was replaced
    params = draw_params(16, augment_generator(3, 11))
    assert torch.equal(out[fg], jitter_colour(images, params, masks)[fg])
    assert out.min() >= 0 and out.max() <= 1 and out.shape == images.shape


def test_same_seed_and_step_same_images_other_steps_differ():
    images, masks = blobs()
    a = augment_images(images, masks, augment_generator(0, 5))
    assert torch.equal(a, augment_images(images, masks, augment_generator(0, 5)))
    for other in (augment_generator(0, 6), augment_generator(1, 5), augment_generator(0, 5, rank=1),
                  augment_generator(0, 5, slot=1)):
        assert not torch.equal(a, augment_images(images, masks, other))
    cl = augment_images(images.contiguous(memory_format=torch.channels_last), masks, augment_generator(0, 5))
    assert torch.equal(cl, a) and cl.is_contiguous(memory_format=torch.channels_last)


def semi_batches(sample_shards, augment: bool):
    """A semi run's config and the device batches of its first mixed step (labelled and
    unlabelled), through the real loader."""
    from sc3d_train.loop.metrics_log import DataWaitClock
    from sc3d_train.loop.resolve import resolve_config
    from sc3d_train.loop.streams import phase_loaders
    from sc3d_train.loop.trainer import device_batches, prepare

    cfg = resolve_config({"shards": str(sample_shards), "out": "unused", "batch_size": 8, "mode": "semi",
                          "labeled_fraction": 0.5, "pretrain_steps": 0, "device": "cpu", "augment": augment,
                          "model": {"base_channels": 4}}, {"tiny": True})
    t = prepare(cfg)
    return cfg, {p: next(it) for p, it in device_batches(t, phase_loaders(t, 0), DataWaitClock()).items()}


def test_step_changes_the_images_only(sample_shards):
    """``augment_step`` on a real mixed batch: every other key (voxels, masks, pose targets,
    cameras) is bit-identical to the batch without augmentation; the images differ; and the
    colour key that finds the objects of unlabelled images equals the stored masks of these
    renders (read from the shard files)."""
    from sc3d_train.loop.phase_step import augment_step

    cfg, plain = semi_batches(sample_shards, augment=False)
    cfg_aug, batches = semi_batches(sample_shards, augment=True)
    assert augment_step(plain, cfg, 0) is plain
    out = augment_step(batches, cfg_aug, 0)
    for phase in ("supervised", "unsupervised"):
        assert set(out[phase]) == set(plain[phase])
        for k, v in plain[phase].items():
            if k == "images":
                assert torch.equal(v, batches[phase][k]) and not torch.equal(v, out[phase][k])
            elif torch.is_tensor(v):
                assert torch.equal(v, out[phase][k]), (phase, k)
            else:
                assert v == out[phase][k]
    assert "masks" not in out["unsupervised"] and "pose_target" in out["supervised"]
    with h5py.File(sorted(sample_shards.glob("*.h5"))[0], "r") as f:
        images = torch.from_numpy(f["images"][:4].reshape(-1, 64, 64, 3)).permute(0, 3, 1, 2).float() / 255
        stored = torch.from_numpy(f["masks"][:4].reshape(-1, 64, 64) > 0)
    assert torch.equal(key_foreground(images, [255, 255, 255]), stored)


def test_fit_augment_trains_and_eval_sees_the_shards_images(sample_shards, tmp_path):
    """A short ``fit --augment`` logs finite losses that differ from the same run without it (the
    step sees other images); its validation and ``eval`` feed the network exactly the shards'
    images (uint8 / 255, read with h5py), caught by a forward pre-hook on the network."""
    from sc3d_train.evaluation.evaluate import evaluate
    from sc3d_train.paper.model import SelfConsistencyNet

    args = ["--shards", sample_shards, "--steps", "3", "--batch-size", "4", *TINY, "--seed", "2"]
    run_cli(main, ["fit", "--out", tmp_path / "plain", *args])
    seen = []

    def record(module, inputs):
        if isinstance(module, SelfConsistencyNet):
            seen.append(inputs[0].detach().clone())

    handle = torch.nn.modules.module.register_module_forward_pre_hook(record)
    try:
        run_cli(main, ["fit", "--out", tmp_path / "aug", *args, "--augment", "--val-every", "3", "--val-views", "24"])
        train_inputs, seen[:] = seen[:3], seen[3:]
        val_inputs = list(seen)
        seen.clear()
        evaluate(tmp_path / "aug" / "checkpoints" / "last.pt", sample_shards, "val", tmp_path / "eval", examples=0)
        eval_inputs = list(seen)
    finally:
        handle.remove()
    a, b = read_csv(tmp_path / "plain" / "metrics.csv"), read_csv(tmp_path / "aug" / "metrics.csv")
    assert all(math.isfinite(float(r["total"])) for r in a + b)
    assert a[0]["total"] != b[0]["total"]

    val_images = []
    for shard in sorted(sample_shards.glob("*.h5")):
        with h5py.File(shard, "r") as f:
            rows = [i for i, s in enumerate(f["split"].asstr()[:]) if s == "val"]
            val_images += [f["images"][r] for r in rows]
    assert val_images, "the sample shards should hold val objects"
    expected = torch.from_numpy(np.concatenate(val_images)).permute(0, 3, 1, 2).float() / 255  # [N*V, 3, S, S]
    for inputs in (val_inputs, eval_inputs):
        got = torch.cat(inputs)
        assert got.shape == expected.shape and torch.equal(got, expected)
    assert len(train_inputs) == 3


def test_colour_key_is_exact_per_pixel():
    """A white image keyed against white is background everywhere, against (250, 250, 250) object
    everywhere; one channel off by 1/255 makes a pixel object."""
    white = torch.ones(1, 3, 4, 4)
    assert not key_foreground(white, [255, 255, 255]).any() and key_foreground(white, [250, 250, 250]).all()
    white[0, 2, 1, 3] = 254 / 255
    assert key_foreground(white, [255, 255, 255]).nonzero().tolist() == [[0, 1, 3]]
