"""The network, the pose parameterisation and the losses (real modules, small configs)."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from sc3d_data.camera import intrinsics, scale_intrinsics
from sc3d_train.losses import LOSS_KEYS, LossWeights, supervised_loss, unsupervised_loss, voxel_loss
from sc3d_train.model import ModelConfig, SelfConsistencyNet, VoxelDecoder
from sc3d_train.pose import angular_error_deg, pose_errors, pose_from_raw, raw_from_pose, wrap_degrees
from sc3d_train.self_consistency import area_downsample


def make_batch(b: int = 3, seed: int = 0) -> dict:
    g = torch.Generator().manual_seed(seed)
    vox = torch.zeros(b, 32, 32, 32)
    vox[:, 8:24, 4:20, 10:22] = 1
    vox[:, 8:11, 20:30, 10:13] = 1
    masks = (torch.rand(b, 64, 64, generator=g) > 0.6).float()
    K = torch.as_tensor(scale_intrinsics(intrinsics(64), 48, 64), dtype=torch.float32)
    return {"images": torch.rand(b, 3, 64, 64, generator=g), "voxels": vox, "masks": masks,
            "masks_sc": (area_downsample(masks, 48) >= 0.5).float(), "K_sc": K.expand(b, 3, 3).contiguous(),
            "distance": torch.full((b,), 2.0), "azimuth": torch.zeros(b), "elevation": torch.full((b,), 30.0)}


@pytest.mark.parametrize("config", [ModelConfig(), ModelConfig.tiny(), ModelConfig.tiny(voxel_decoder="1tube"),
                                    ModelConfig.tiny(image_size=32, voxel_resolution=16)])
def test_output_shapes(config):
    torch.manual_seed(0)
    model = SelfConsistencyNet(config).eval()
    s, g = config.image_size, config.voxel_resolution
    with torch.no_grad():
        out = model(torch.rand(2, 3, s, s))
    assert out.voxel_logits.shape == (2, g, g, g)
    assert out.mask_logits.shape == (2, s, s)
    assert out.azimuth.shape == out.elevation.shape == (2,)
    assert out.pose_raw.shape == (2, 3)
    assert out.z_mean.shape == out.z_logvar.shape == (2, config.shape_dim)
    assert ((out.azimuth >= 0) & (out.azimuth < 360)).all() and (out.elevation.abs() < 90).all()
    assert len(model.voxel_decoder.branches) == (3 if config.voxel_decoder == "3tube" else 1)


@pytest.mark.parametrize("channels", [4, 8])
def test_backward_on_images_permuted_from_hwc(channels):
    """Images straight from the shards ([B, S, S, 3] permuted, channels-last strides) with a small
    model: forward and backward work (a strided 1x1 conv crashed torch's CPU backward here)."""
    torch.manual_seed(0)
    model = SelfConsistencyNet(ModelConfig.tiny(base_channels=channels))
    images = torch.rand(6, 64, 64, 3).permute(0, 3, 1, 2)
    out = model(images)
    (out.voxel_logits.mean() + out.mask_logits.mean() + out.pose_raw.sum()).backward()
    assert all(torch.isfinite(p.grad).all() for p in model.parameters() if p.grad is not None)


def test_vae_samples_in_training_and_uses_the_mean_in_eval():
    torch.manual_seed(0)
    model = SelfConsistencyNet(ModelConfig.tiny())
    x = torch.rand(2, 3, 64, 64)
    model.eval()
    with torch.no_grad():
        a, b = model(x).voxel_logits, model(x).voxel_logits
    torch.testing.assert_close(a, b)
    model.train()
    with torch.no_grad():
        c, d = model(x).voxel_logits, model(x).voxel_logits
    assert not torch.allclose(c, d)


def test_voxel_tubes_are_transposed_into_x_y_z():
    """Each branch's channel axis is a different grid axis: make every branch output its channel
    index and the averaged volume must be (i + j + k) / 3 at [i, j, k]."""
    cfg = ModelConfig.tiny(voxel_resolution=8)
    dec = VoxelDecoder(cfg)
    ramp = torch.arange(8.0).view(1, 8, 1, 1).expand(1, 8, 8, 8)
    for branch in dec.branches.values():
        branch.register_forward_hook(lambda mod, inp, out: ramp.expand_as(out))
    v = dec(torch.zeros(1, cfg.shape_dim))[0]
    i, j, k = torch.meshgrid(*(torch.arange(8.0),) * 3, indexing="ij")
    torch.testing.assert_close(v, (i + j + k) / 3)


def test_config_round_trip_and_bad_configs():
    cfg = ModelConfig.tiny(voxel_decoder="1tube")
    assert ModelConfig.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(ValueError, match="voxel_decoder"):
        ModelConfig(voxel_decoder="2tube")
    with pytest.raises(ValueError, match="image_size"):
        ModelConfig(image_size=48)
    with pytest.raises(ValueError, match="unknown ModelConfig keys"):
        ModelConfig.from_dict({**cfg.to_dict(), "depth": 3})
    with pytest.raises(ValueError, match=r"images must be \[B, 3, 64, 64\]"):
        SelfConsistencyNet(cfg)(torch.rand(1, 3, 32, 32))


def test_pose_wrap():
    assert float(angular_error_deg(torch.tensor(359.0), torch.tensor(1.0))) == pytest.approx(2.0)
    assert float(angular_error_deg(1.0, 359.0)) == pytest.approx(2.0)
    assert float(angular_error_deg(180.0, 0.0)) == pytest.approx(180.0)
    assert float(wrap_degrees(370.0)) == pytest.approx(10.0)
    az, el = torch.tensor([359.5, 0.5, 180.0]), torch.tensor([30.0, -10.0, 60.0])
    az2, el2 = pose_from_raw(raw_from_pose(az, el))
    assert float(angular_error_deg(az2, az).max()) < 1e-3
    torch.testing.assert_close(el2, el, atol=1e-3, rtol=0)
    # the raw azimuth vectors of 359.5 and 0.5 deg are neighbours (no 0/360 boundary)
    raw = raw_from_pose(az, el)
    assert float((raw[0, :2] - raw[1, :2]).norm()) < 0.02
    e = pose_errors(torch.tensor([359.0, 90.0]), torch.tensor([30.0, 30.0]),
                    torch.tensor([1.0, 150.0]), torch.tensor([30.0, 40.0]))
    assert e["azimuth_mean"] == pytest.approx(31.0) and e["azimuth_acc30"] == pytest.approx(0.5)
    assert e["elevation_median"] == pytest.approx(5.0) and e["count"] == 2
    # flip-aware diagnostic: within 30 deg of the true azimuth or of the true azimuth + 180
    f = pose_errors(torch.tensor([10.0, 200.0, 100.0, 355.0]), torch.zeros(4), torch.zeros(4), torch.zeros(4))
    assert f["azimuth_acc30"] == pytest.approx(0.5) and f["azimuth_flip_acc30"] == pytest.approx(0.75)


def test_pose_head_gets_gradient_from_sc_loss_alone():
    torch.manual_seed(0)
    model = SelfConsistencyNet(ModelConfig.tiny())
    batch = make_batch()
    out = model(batch["images"])
    losses = supervised_loss(out, batch)
    assert set(losses) == set(LOSS_KEYS)
    model.zero_grad()
    losses["lsc"].backward()
    assert model.pose_head.weight.grad is not None and model.pose_head.weight.grad.abs().sum() > 0
    assert model.fc_pose_code.weight.grad.abs().sum() > 0
    # L_sc with ground-truth voxels does not touch the decoders
    assert all(p.grad is None or p.grad.abs().sum() == 0 for p in model.voxel_decoder.parameters())
    assert all(p.grad is None or p.grad.abs().sum() == 0 for p in model.mask_decoder.parameters())


def test_supervised_loss_weights_and_never_reads_gt_pose():
    torch.manual_seed(0)
    model = SelfConsistencyNet(ModelConfig.tiny())
    batch = make_batch()
    out = model(batch["images"])
    w = LossWeights()
    a = supervised_loss(out, batch, w)
    expected = w.w3d * a["l3d"] + w.w2d * a["l2d"] + w.wsc * (w.ray * a["ray"] + w.proj * a["proj"]) + w.wkl * a["kl"]
    torch.testing.assert_close(a["total"], expected)
    b = supervised_loss(out, {**batch, "azimuth": batch["azimuth"] + 123.0, "elevation": -batch["elevation"]}, w)
    torch.testing.assert_close(a["total"], b["total"])


def test_voxel_loss_prefers_the_truth_and_weights_positives():
    vox = make_batch(1)["voxels"]
    good_logits = (vox * 2 - 1) * 6
    good = voxel_loss(good_logits, vox)
    assert good < 0.05 < voxel_loss(torch.zeros_like(vox), vox)
    pos = vox.nonzero()[0].tolist()
    neg = (1 - vox).nonzero()[0].tolist()
    miss, extra = good_logits.clone(), good_logits.clone()
    miss[tuple(pos)] = -6.0   # one missed occupied voxel
    extra[tuple(neg)] = 6.0   # one spurious voxel
    def delta(logits, pw):
        return float(voxel_loss(logits, vox, pos_weight=pw) - voxel_loss(good_logits, vox, pos_weight=pw))

    assert delta(miss, 3.0) > delta(extra, 3.0) > 0
    # the positive weight scales the cost of missed occupied voxels only
    assert delta(miss, 3.0) > 1.5 * delta(miss, 1.0)
    assert delta(extra, 3.0) == pytest.approx(delta(extra, 1.0), rel=1e-3)


def test_unsupervised_loss_updates_encoder_and_voxel_decoder_not_mask_decoder():
    torch.manual_seed(0)
    model = SelfConsistencyNet(ModelConfig.tiny())
    batch = make_batch()
    unlabeled = {k: batch[k] for k in ("images", "K_sc", "distance")}
    out = model(unlabeled["images"])
    losses = unsupervised_loss(out, unlabeled)
    assert set(losses) == set(LOSS_KEYS) and float(losses["l3d"]) == 0.0
    losses["total"].backward()
    grad = lambda mod: sum(float(p.grad.abs().sum()) for p in mod.parameters() if p.grad is not None)  # noqa: E731
    assert grad(model.voxel_decoder) > 0 and grad(model.encoder) > 0 and grad(model.pose_head) > 0
    assert all(p.grad is None or float(p.grad.abs().sum()) == 0 for p in model.mask_decoder.out.parameters())


def test_tiny_model_fits_one_batch():
    """A few Adam steps on one batch lower the supervised loss (the model can learn)."""
    torch.manual_seed(0)
    model = SelfConsistencyNet(ModelConfig.tiny())
    batch = make_batch(4)
    opt = torch.optim.Adam(model.parameters(), lr=2e-3)
    history = []
    for _ in range(20):
        opt.zero_grad()
        losses = supervised_loss(model(batch["images"]), batch)
        losses["total"].backward()
        opt.step()
        history.append({k: float(v.detach()) for k, v in losses.items()})
    assert all(np.isfinite(h["total"]) for h in history)
    assert history[-1]["l3d"] < 0.85 * history[0]["l3d"] and history[-1]["total"] < history[0]["total"]
