"""The network, the pose parameterisation and the losses (real modules, small configs)."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from sc3d_data.geometry.camera import intrinsics, scale_intrinsics
from sc3d_train.settings.config import LossWeights, ModelConfig
from sc3d_train.paper.losses import LOSS_KEYS, supervised_loss, unsupervised_loss, voxel_loss
from sc3d_train.paper.model import SelfConsistencyNet, VoxelDecoder
from sc3d_train.paper.pose import (PoseGrid, angular_error_deg, pose_classification_loss, pose_errors, pose_from_logits,
                                   rotation_error_deg, wrap_degrees)
from sc3d_train.paper.self_consistency import area_downsample
from tests.conftest import assert_learnt, train_seed


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
    assert out.pose_logits.shape == (2, 24 + 5)
    assert out.z_mean.shape == out.z_logvar.shape == (2, config.shape_dim)
    assert ((out.azimuth >= 0) & (out.azimuth < 360)).all()
    assert ((out.elevation >= 10) & (out.elevation <= 50)).all()  # the default grid's range
    assert len(model.voxel_decoder.branches) == (3 if config.voxel_decoder == "3tube" else 1)


@pytest.mark.parametrize("channels", [4, 8])
def test_backward_on_images_permuted_from_hwc(channels):
    """Images straight from the shards ([B, S, S, 3] permuted, channels-last strides) with a small
    model: forward and backward work (a strided 1x1 conv crashed torch's CPU backward here)."""
    torch.manual_seed(0)
    model = SelfConsistencyNet(ModelConfig.tiny(base_channels=channels))
    images = torch.rand(6, 64, 64, 3).permute(0, 3, 1, 2)
    out = model(images)
    (out.voxel_logits.mean() + out.mask_logits.mean() + out.pose_logits.sum()).backward()
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


def test_pose_from_logits_hand_derived():
    """Soft-argmax over the argmax bin and its two neighbours (15 deg bins): weights 1/3, 2/3, 0
    around bin 0 give 0 - 15/3 = -5 -> 355 deg (across the 0/360 wrap); uniform elevation logits
    give the mean of 10..50 = 30; elevation logits (ln 1, ln 3, -inf...) give (10 + 3 * 20) / 4."""
    grid = PoseGrid()  # 24 azimuths, 5 elevations 10..50
    logits = torch.full((2, 29), -1e9)
    logits[0, 0], logits[0, 23] = math.log(2.0), 0.0        # bin 1 stays at -1e9
    logits[0, 24:] = 0.0
    logits[1, 7], logits[1, 6], logits[1, 8] = 5.0, -1e9, -1e9   # one bin: exactly 105 deg
    logits[1, 24], logits[1, 25] = 0.0, math.log(3.0)
    az, el = pose_from_logits(logits, grid)
    torch.testing.assert_close(az, torch.tensor([355.0, 105.0]), atol=1e-4, rtol=0)
    torch.testing.assert_close(el, torch.tensor([30.0, 17.5]), atol=1e-4, rtol=0)
    # candidate index a * E + e: 7 * 5 + 3 = 38 -> azimuth bin 7, elevation bin 3
    assert [int(x) for x in grid.split(torch.tensor(38))] == [7, 3]
    ca, ce = grid.candidates()
    assert float(ca[38]) == 105.0 and float(ce[38]) == 40.0
    # cross-entropy of a uniform head = ln 24 + ln 5; an ignored target (-1) contributes nothing
    loss = pose_classification_loss(torch.zeros(2, 29), torch.tensor([38, -1]), grid)
    assert float(loss) == pytest.approx(math.log(24) + math.log(5))


def test_rotation_error_hand_derived():
    from sc3d_data.geometry.camera import look_at_rotation

    R0 = look_at_rotation(np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, 30.0]))
    R1 = look_at_rotation(np.array([90.0, 180.0, 30.0]), np.array([0.0, 0.0, 30.0]))
    # at equal elevations the two cameras differ by a turn about the world y axis by the azimuth
    # difference, so the geodesic angle is that difference (also at elevation 30)
    np.testing.assert_allclose(rotation_error_deg(R0, R1), [90.0, 180.0, 30.0], atol=1e-6)
    # azimuth 0 -> elevation 30 at azimuth 0: a rotation by 30 deg about the camera x axis
    np.testing.assert_allclose(rotation_error_deg(R0[0], look_at_rotation(0.0, 30.0)), 30.0, atol=1e-6)
    e = pose_errors(torch.zeros(4), torch.zeros(4), torch.zeros(4), torch.zeros(4),
                    rotation_error=[5.0, 20.0, 40.0, 100.0])
    assert e["rotation_median"] == pytest.approx(30.0) and e["rotation_mean"] == pytest.approx(41.25)
    assert e["rotation_acc15"] == 0.25 and e["rotation_acc30"] == 0.5


def test_voxel_loss_hand_derived_and_supervised_loss_never_reads_gt_pose():
    """L_3D at logits 0 (p = 1/2 everywhere) for a grid with n1 of N voxels occupied:
    BCE(pos_weight 3) = ln 2 * (3 n1 + (N - n1)) / N; soft IoU = (n1 / 2) / (N / 2 + n1 / 2),
    so L_IoU = exp(1 - n1 / (N + n1)) - 1. With only w3d = 1 the total is that value."""
    batch = make_batch(1)
    vox = batch["voxels"]
    n1, n = float(vox.sum()), float(vox.numel())
    expected = math.log(2) * (3 * n1 + (n - n1)) / n + math.exp(1 - n1 / (n + n1)) - 1
    assert float(voxel_loss(torch.zeros_like(vox), vox)) == pytest.approx(expected, rel=1e-5)
    torch.manual_seed(0)
    model = SelfConsistencyNet(ModelConfig.tiny())
    out = model(batch["images"])
    out.voxel_logits = torch.zeros_like(out.voxel_logits)
    only_3d = LossWeights(w3d=1.0, w2d=0.0, wsc=0.0, wkl=0.0, wpose=0.0)
    assert float(supervised_loss(out, batch, only_3d)["total"].detach()) == pytest.approx(expected, rel=1e-5)
    w = LossWeights()
    grid = model.pose_grid
    a = supervised_loss(out, batch, w, grid)
    b = supervised_loss(out, {**batch, "azimuth": batch["azimuth"] + 123.0, "elevation": -batch["elevation"]}, w, grid)
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
    losses = unsupervised_loss(out, unlabeled, LossWeights(wpose_unlabeled=1.0), grid=model.pose_grid)
    # no 3D/2D label terms are reported for unlabelled images (nothing is optimised there)
    assert set(losses) == set(LOSS_KEYS) - {"l3d", "l2d"}
    assert float(losses["pose"].detach()) > 0  # the pose search between predicted voxels and mask
    losses["total"].backward()
    grad = lambda mod: sum(float(p.grad.abs().sum()) for p in mod.parameters() if p.grad is not None)  # noqa: E731
    assert grad(model.voxel_decoder) > 0 and grad(model.encoder) > 0 and grad(model.pose_head) > 0
    assert all(p.grad is None or float(p.grad.abs().sum()) == 0 for p in model.mask_decoder.out.parameters())


@pytest.mark.learnt
def test_tiny_model_fits_one_batch():
    """A few Adam steps on one batch lower the supervised loss (the model can learn)."""
    torch.manual_seed(train_seed())
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
    assert_learnt(("L_3D after / before 20 steps", history[-1]["l3d"] / history[0]["l3d"], "<", 0.85),
                  ("total loss after / before 20 steps", history[-1]["total"] / history[0]["total"], "<", 1.0))


def test_unlabelled_pose_gate_keeps_only_searches_that_agree_with_the_head():
    """``unlabeled_pose_gate`` N: L_pose is the azimuth cross-entropy over the images whose searched
    azimuth bin lies within N bins (circularly) of the head's top bin, recomputed here from the
    search; N = 12 (half the 24 bins) trusts every image, as no gate (-1) does."""
    import torch.nn.functional as F

    from sc3d_train.paper.pose_search import search_at_head_elevation

    torch.manual_seed(0)
    model = SelfConsistencyNet(ModelConfig.tiny())
    batch = make_batch(b=6)
    unlabeled = {k: batch[k] for k in ("images", "K_sc", "distance")}
    out = model(unlabeled["images"])
    grid = model.pose_grid
    loss = {gate: unsupervised_loss(out, unlabeled, LossWeights(unlabeled_pose_gate=gate), grid)["pose"]
            for gate in (-1, 0, 3, 12)}
    assert float(loss[12].detach()) == pytest.approx(float(loss[-1].detach()))
    occupancy = torch.sigmoid(out.voxel_logits.float())
    masks = area_downsample(torch.sigmoid(out.mask_logits.float()), 48)  # the loss's size without masks_sc
    target = search_at_head_elevation(occupancy, masks, unlabeled["distance"], unlabeled["K_sc"], out.pose_logits,
                                      grid, LossWeights())
    a = grid.azimuth_bins
    searched, head = grid.split(target)[0], out.pose_logits[:, :a].argmax(1)
    kept = []
    for gate in (0, 3):
        gap = torch.minimum((searched - head) % a, (head - searched) % a)
        keep = gap <= gate
        expected = F.cross_entropy(out.pose_logits[keep, :a].float(), searched[keep]) if keep.any() else 0.0
        assert float(loss[gate].detach()) == pytest.approx(float(torch.as_tensor(expected).detach()), rel=1e-5)
        kept.append(int(keep.sum()))
    assert kept[0] < 6 and kept[1] > 0  # the gate drops some images and keeps some
