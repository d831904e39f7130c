"""The fewest images a training pass may hold: the network's BatchNorm layers normalise each
channel over the batch and the feature plane, and in training mode a layer that sees one value
per channel raises "Expected more than 1 value per channel when training". At 64 px the deepest
layers see 2x2 features, so one image is enough; at 32 px they see 1x1, and a pass of one image
(``--batch-size 1``, or a ``semi`` batch whose labelled or unlabelled part is one image per rank)
crashed at the first step of its phase, a ``semi`` run after its whole pretraining. Checked before
any work (``trainer.prepare``)."""
from __future__ import annotations

import math

import torch

from sc3d_train.settings.config import RunConfig
from sc3d_train.loop.schedule import batch_split, mixed_batch


def smallest_norm_plane(cfg: RunConfig) -> int:
    """Values per channel per image at the network's smallest BatchNorm input (``H * W`` of its
    feature plane, 1 for a flat one), measured by a forward pass of 2 blank images through the
    run's network, built on the CPU in eval mode (no statistics updated; random state: the run
    seeds everything after this). Without BatchNorm layers: a large number."""
    from sc3d_train.loop.checkpoint_model import build_model

    model = build_model(cfg).eval()
    planes: list[int] = []
    hooks = [m.register_forward_hook(lambda _m, inputs, _o: planes.append(math.prod(inputs[0].shape[2:])))
             for m in model.modules() if isinstance(m, torch.nn.modules.batchnorm._BatchNorm)]
    try:
        size = cfg.model.image_size
        with torch.no_grad():
            model(torch.zeros(2, 3, size, size), torch.zeros(2, cfg.model.shape_dim))
    finally:
        for h in hooks:
            h.remove()
    return min(planes, default=2**31)


def check_mixed_parts(cfg: RunConfig, mixed: int, labelled: int, ranks: int) -> None:
    """``ValueError`` when a rank's mixed batch of ``mixed`` images has no labelled image although
    ``semi_labeled_share`` asks for some: one image per rank (``--semi --batch-size 2`` on 2 ranks)
    went to the unlabelled part whole, so the run silently trained with a share of 0 (the
    ``--semi-batch-size`` floor of 2 counts all ranks together)."""
    if cfg.semi_labeled_share > 0 and labelled == 0:
        raise ValueError(f"the second phase's batch of {mixed} image per rank cannot hold a labelled and an unlabelled "
                         f"image (--semi-labeled-share {cfg.semi_labeled_share}); raise --semi-batch-size (or "
                         f"--batch-size) to at least 2 per rank ({2 * ranks} over {ranks} ranks), or use "
                         "--semi-labeled-share 0")


def check_batch_parts(cfg: RunConfig, local_batch: int) -> None:
    """``ValueError`` naming the options when a forward pass of a step would give a BatchNorm layer
    one value per channel: one image per rank (the batch; in a ``semi`` run's second phase, its
    labelled or unlabelled part) where :func:`smallest_norm_plane` (measured only then) is 1."""
    mixed = labelled = unlabelled = 0
    if cfg.mode == "semi" and cfg.pretrain_steps < cfg.steps:
        mixed = mixed_batch(cfg, local_batch)
        labelled, unlabelled = batch_split(cfg, mixed)  # (0, mixed) at --semi-labeled-share 0
        check_mixed_parts(cfg, mixed, labelled, cfg.batch_size // local_batch)
    if min(n for n in (local_batch, labelled, unlabelled) if n) >= 2 or (values := smallest_norm_plane(cfg)) >= 2:
        return
    where = f"at {cfg.model.image_size} px the network's deepest BatchNorm sees {values} value per channel and image"
    if local_batch < 2:
        raise ValueError(f"batch size {cfg.batch_size} gives {local_batch} image per rank; {where}, so a training "
                         "step needs at least 2 (BatchNorm normalises over the batch): raise --batch-size")
    split = f"{labelled} labelled and {unlabelled} unlabelled" if labelled else f"{unlabelled} unlabelled"
    raise ValueError(f"the second phase's batch of {mixed} images per rank splits into {split} images; {where}, "
                     "so each pass of a step needs at least 2 (BatchNorm normalises over the batch): raise "
                     "--semi-batch-size (or --batch-size), or move --semi-labeled-share")
