"""Defects of ``fit --semi`` under torchrun found by the attack on DDP and semi runs
(2026-12-07, atk_ddp), each test failing without its fix. Real 2-rank gloo runs of the tiny
model on the bundled sample meshes (about 10 s each)."""
from __future__ import annotations

from tests.test_train import TINY, _torchrun_fit, read_csv


# ----------------------------------------------------------------------------- D1: the pure unlabelled phase
def test_ddp_semi_with_no_labelled_share_trains_its_unlabelled_phase(sample_shards, tmp_path):
    """``--semi --semi-labeled-share 0`` (the paper's pure unlabelled fine-tuning) under torchrun:
    the unlabelled phase's pass went through the DDP wrapper, whose output holds the mask decoder's
    mask (the loss reads it detached). DDP's search for unused parameters walks the graph from the
    outputs, so it waited for the mask decoder's gradients, which never came: the second
    unlabelled step died with DDP's 'Expected to have finished reduction in the prior iteration'
    traceback on every rank. docs/training.md promises this phase under DDP."""
    out = tmp_path / "run"
    _torchrun_fit("--shards", sample_shards, "--out", out, "--steps", 5, "--checkpoint-every", 5,
                  "--semi", "--labeled-fraction", "0.5", "--pretrain-steps", 2, "--semi-labeled-share", 0,
                  "--val-every", 0)
    rows = read_csv(out / "metrics.csv")
    assert [r["phase"] for r in rows] == ["supervised"] * 2 + ["unsupervised"] * 3


def test_the_mask_decoder_outside_the_graph_gives_the_same_outputs():
    """``forward(..., mask_grad=False)`` (the unlabelled-only pass) computes the same outputs; only
    the mask leaves the autograd graph, as the loss already detaches it."""
    import torch

    from sc3d_train.paper.model import SelfConsistencyNet
    from sc3d_train.settings.config import ModelConfig, TINY_MODEL

    torch.manual_seed(0)
    net = SelfConsistencyNet(ModelConfig(**TINY_MODEL)).train()
    images, noise = torch.rand(2, 3, 64, 64), torch.randn(2, net.config.shape_dim)
    state = {k: v.clone() for k, v in net.state_dict().items()}
    a = net(images, noise)
    net.load_state_dict(state)  # the same BatchNorm statistics for the second pass
    b = net(images, noise, mask_grad=False)
    assert torch.equal(a.mask_logits, b.mask_logits) and torch.equal(a.voxel_logits, b.voxel_logits)
    assert a.mask_logits.requires_grad and not b.mask_logits.requires_grad and b.voxel_logits.requires_grad
