"""Issue 24 item 3 at test scale: the unlabelled images of the mixed phase of ``fit --semi`` must
not make the pose worse than training on the labelled images alone."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from sc3d_cli.train import main
from tests.conftest import TRAINED_RUN_STEPS, assert_learnt, run_cli

#: steps of the mixed phase (batch 8 of the shared run: 4 labelled + 4 unlabelled images)
MIXED = 20


def median_rotation_error(checkpoint, dataset) -> float:
    """Median over every view of ``dataset`` of the rotation error (degrees) of the test-time
    self-consistent pose (eval's default) of ``checkpoint``."""
    from sc3d_train.loop.checkpoint_model import load_model
    from sc3d_train.paper.metrics import predict_dataset

    model, cfg, _ = load_model(checkpoint, "cpu")
    rows, _ = predict_dataset(model, dataset, "cpu", keep=0, pose_from="search", loss_weights=cfg.loss_weights)
    return float(np.median([r["rotation_error"] for r in rows]))


def semi_run_at_boundary(trained_run, out, **loss_weights):
    """A ``semi`` run folder whose checkpoint sits at the phase boundary (step =
    ``TRAINED_RUN_STEPS``) with the shared supervised run's weights, Adam state and RNG, so
    ``fit --resume`` trains only the mixed phase (``MIXED`` steps) from a network that has learnt
    pose; ``loss_weights`` override the run's. Returns the run's config."""
    from sc3d_train.loop.checkpoint import checkpoint_config, load_checkpoint, save_checkpoint
    from sc3d_train.loop.schedule import data_position

    source = trained_run / "checkpoints" / "last.pt"
    ckpt = load_checkpoint(source)
    start = checkpoint_config(source, ckpt)
    cfg = replace(start, mode="semi", out=str(out), labeled_fraction=0.15, pretrain_steps=TRAINED_RUN_STEPS,
                  steps=TRAINED_RUN_STEPS + MIXED, val_every=0, checkpoint_every=TRAINED_RUN_STEPS + MIXED,
                  loss_weights=replace(start.loss_weights, **loss_weights))
    out.mkdir(parents=True)
    cfg.save(out / "config.yaml")
    save_checkpoint(out, {**{k: ckpt[k] for k in ("model", "optimizer", "scaler", "rng")},
                          "step": TRAINED_RUN_STEPS, "config": cfg.to_dict(),
                          "data_position": data_position(cfg, TRAINED_RUN_STEPS, cfg.batch_size)})
    return cfg


@pytest.mark.learnt
def test_semi_phase_keeps_the_pose_of_labelled_training(trained_run, sample_shards, tmp_path):
    """From the shared supervised run (its pose learnt with labels on all 8 training objects),
    ``MIXED`` mixed steps of ``semi`` (15% labelled: 4 objects) against the same steps with every
    unlabelled loss weight 0 (the labelled half alone: what labelled-only training would do in
    those steps). Figure: median rotation error of semi minus that of the labelled-only
    continuation, on the 4 training objects whose labels the semi run never reads (the images its
    unlabelled pass learns from).

    Found on the way (branch i24, trained seed 0, semi seeds 0-2, median rotation error on the
    unlabelled objects after 20 mixed steps; 0.4 deg at the start): labelled-only continuation 3.4 /
    1.6 / 9.9 deg; semi with the unlabelled pose pseudo-label (``wpose_unlabeled`` 1, the earlier
    default) 17.7 / 45.0 / 15.5; without it (0, now the default) 3.9 / 4.3 / 8.6; with the
    pseudo-label but no unlabelled L_sc 31.6 / 30.0 / 45.3. The pseudo-label on the searched azimuth
    is what cost the pose; a confidence gate on it (``unlabeled_pose_gate`` 1) did not help.
    Measured for this test with ``wpose_unlabeled`` 1 (scripts/test_spread.py --seeds 0-2
    --threads 1): unlabelled objects +14.3, +60.0, +59.5 deg. With the default 0, 20 runs
    (--seeds 0-9 --threads 1,2, 2-core Xeon, 2026-11-25): -37.2 to +7.5 deg (median -2.6); with
    the search's head prior weight 0.005 (was 0.02), 12 runs (--seeds 0-5 --threads 1,2, 2-core
    CPU box, 2026-11-27): -7.4 to -0.1 deg (median -2.1).
    BOUND 12 deg: the requirement (no worse) with room for that spread (4.5 deg above its worst),
    below a whole 15-deg azimuth bin, which every seed of the earlier default broke."""
    from sc3d_train.data.dataset import ShardDataset

    ends = {}
    for name, weights in (("semi", {}),
                          ("labelled only", dict(wsc_unlabeled=0.0, wkl_unlabeled=0.0, wpose_unlabeled=0.0))):
        out = tmp_path / name.replace(" ", "_")
        cfg = semi_run_at_boundary(trained_run, out, **weights)
        run_cli(main, ["fit", "--out", out, "--resume", "--no-progress"])
        ends[name] = out / "checkpoints" / "last.pt"
    # only the unlabelled training objects: the one val object is at chance in both runs (about
    # 90 deg), so the difference there is noise (-30 to +45 deg over 11 runs) and asserts nothing
    sets = {"unlabelled objects": ShardDataset(sample_shards, "train", subset="unlabeled", labeled_fraction=0.15,
                                               seed=cfg.seed)}
    figures = []
    for name, dataset in sets.items():
        semi, only = (median_rotation_error(ends[k], dataset) for k in ("semi", "labelled only"))
        print(f"{name}: median rotation error semi {semi:.1f}, labelled only {only:.1f} deg")
        figures.append((f"semi minus labelled-only, median rotation error (deg), {name}", semi - only, "<=",
                        BOUNDS[name]))
    assert_learnt(*figures)


#: semi may be at most this much worse than the labelled-only continuation (degrees; docstring)
BOUNDS = {"unlabelled objects": 12.0}
