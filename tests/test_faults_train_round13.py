"""Defects of the training half found by the thirteenth attack on the commands (2026-11-28), each
test failing without its fix: a pass of a step with one image per rank at 32 px (a ``semi`` run's
second phase split 2 + 1, ``--batch-size 1``) crashing in BatchNorm after the pretraining had run; a
Ctrl-C that landed in a checkpoint's write reported as a full disk; semi-only settings in a
``--config`` file recorded and silently ignored by a supervised run; ``eval`` silent on categories
the run never trained on. Real runs of the tiny model
on the bundled sample meshes."""
from __future__ import annotations

import pytest

from sc3d_cli.train import main
from tests.conftest import run_cli
from tests.test_train import TINY
from conftest import error_lines


# ----------------------------------------------------------------------------- one image per pass
@pytest.fixture(scope="module")
def shards_32px(tmp_path_factory):
    """The sample meshes at 32 px, 4 views, voxelized: the network's deepest BatchNorm layers see
    1x1 features at this size (2x2 at 64 px)."""
    from sc3d_cli.data import main as data_main
    from tests.conftest import SAMPLE_MESHES

    out = tmp_path_factory.mktemp("px32") / "shards"
    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES, "--out", out, "--image-size", 32, "--views", 4,
                        "--voxelize", "--split", "random:1,0", "--workers", 1, "--no-progress"])
    return out


@pytest.mark.parametrize("batch,share,semi_batch,message", [
    (1, None, None, "batch size 1 gives 1 image per rank; at 32 px the network's deepest BatchNorm sees 1 value "
                    "per channel and image, so a training step needs at least 2"),
    (3, 0.5, None, "the second phase's batch of 3 images per rank splits into 2 labelled and 1 unlabelled images"),
    (4, 0.5, 2, "the second phase's batch of 2 images per rank splits into 1 labelled and 1 unlabelled images"),
    (4, 0.9, None, "splits into 3 labelled and 1 unlabelled images"),
], ids=["batch-1", "semi-2+1", "semi-batch-2", "share-0.9"])
def test_a_pass_of_one_image_at_32px_is_refused_before_any_training(shards_32px, tmp_path, batch, share,
                                                                     semi_batch, message):
    """At 32 px a pass of one image gives a BatchNorm layer one value per channel (by hand:
    ``round(3 * 0.5)`` = 2 labelled + 1 unlabelled; ``--semi-batch-size 2``: 1 + 1; share 0.9 of
    4: 3 + 1). Each was accepted, trained its pretraining (a checkpoint at the phase boundary) and
    died at the first mixed step with torch's "Expected more than 1 value per channel"; now one
    line naming the options, and no checkpoint."""
    out = tmp_path / "run"
    semi = ["--semi", "--labeled-fraction", 0.5, "--semi-labeled-share", share] if share is not None else []
    res = run_cli(main, ["fit", "--shards", shards_32px, "--out", out, "--steps", 4, "--batch-size", batch, *TINY,
                         "--val-every", 0, *semi, *(["--semi-batch-size", semi_batch] if semi_batch else [])],
                  expect_exit=1)
    errors = error_lines(res.output)
    assert len(errors) == 1 and message in errors[0] and "Traceback" not in res.output, res.output
    assert "BatchNorm normalises over the batch" in errors[0]
    assert not (out / "checkpoints").exists()


def test_a_pass_of_one_image_at_64px_trains_and_two_at_32px_too(sample_shards, shards_32px, tmp_path):
    """The controls: at 64 px the deepest features are 2x2, so the 2 + 1 split the check refuses
    at 32 px trains into its mixed phase; at 32 px a 2 + 2 split trains."""
    for shards, batch in ((sample_shards, 3), (shards_32px, 4)):
        out = tmp_path / f"run{batch}"
        run_cli(main, ["fit", "--shards", shards, "--out", out, "--steps", 3, "--batch-size", batch, *TINY,
                       "--val-every", 0, "--semi", "--labeled-fraction", 0.5, "--pretrain-steps", 2])
        assert (out / "checkpoints" / "step_000003.pt").is_file()


# ----------------------------------------------------------------------------- Ctrl-C in a checkpoint's write
def test_a_ctrl_c_during_a_checkpoint_write_is_an_interrupt_not_a_full_disk(tmp_path, monkeypatch):
    """A Ctrl-C (``KeyboardInterrupt``) raised inside the third write of ``torch.save`` (the
    user's key, injected at the file) came back as ``CheckpointError: ... unexpected pos ...; free
    space and ...``; now it is raised as itself, and neither temporary file is left."""
    import sc3d_train.loop.atomic_save as atomic_save
    import torch

    from sc3d_train.loop.checkpoint import save_checkpoint

    real = atomic_save.create_new_file

    class CtrlCAtThirdWrite:
        def __init__(self, f):
            self.f, self.writes = f, 0

        def write(self, data):
            self.writes += 1
            if self.writes == 3:
                raise KeyboardInterrupt
            return self.f.write(data)

        def __getattr__(self, name):
            return getattr(self.f, name)

        def __enter__(self):
            self.f.__enter__()
            return self

        def __exit__(self, *exc):
            return self.f.__exit__(*exc)

    monkeypatch.setattr(atomic_save, "create_new_file", lambda path: CtrlCAtThirdWrite(real(path)))
    payload = {"step": 5, "model": {"w": torch.arange(100_000.0)}}
    with pytest.raises(KeyboardInterrupt):
        save_checkpoint(tmp_path, payload)
    assert sorted(p.name for p in (tmp_path / "checkpoints").iterdir()) == []


# ----------------------------------------------------------------------------- semi settings in a supervised config file
def test_semi_settings_in_a_config_file_without_semi_mode_are_refused(sample_shards, tmp_path):
    """A file with ``pretrain_steps``, ``semi_lr`` and ``labeled_fraction`` but no ``mode: semi``
    trained a supervised run whose config.yaml then looked like a semi one; now one line naming
    the file and the settings, before training. A run's own config.yaml (which records these at
    their defaults) is still a valid --config."""
    from sc3d_train.loop.resolve import check_mode_options
    from sc3d_train.settings.config import RunConfig

    forgot = tmp_path / "semi_forgot.yaml"
    forgot.write_text(f"shards: {sample_shards}\nsteps: 4\nbatch_size: 4\nval_every: 0\nlabeled_fraction: 0.3\n"
                      "pretrain_steps: 2\nsemi_lr: 0.0001\n")
    res = run_cli(main, ["fit", "--config", forgot, "--out", tmp_path / "run", *TINY], expect_exit=1)
    errors = error_lines(res.output)
    assert len(errors) == 1 and errors[0].startswith(f"Error: {forgot}: labeled_fraction: 0.3 (read by semi and "
                                                     "labeled-only runs), pretrain_steps: 2 (read by semi runs), "
                                                     "semi_lr: 0.0001 (read by semi runs): not read by a supervised "
                                                     "run"), res.output
    assert not (tmp_path / "run" / "checkpoints").exists()
    own = tmp_path / "own.yaml"
    cfg = RunConfig(shards=str(sample_shards), out=str(tmp_path / "old"))
    cfg.save(own)
    check_mode_options(cfg, {}, own)  # a supervised run's own file: no error
    semi = RunConfig(shards=str(sample_shards), out=str(tmp_path / "old"), mode="semi", pretrain_steps=2, steps=4)
    check_mode_options(semi, {}, forgot)  # read by a semi run: no error


# ----------------------------------------------------------------------------- eval on categories never trained on
def test_eval_notes_categories_the_run_never_trained_on(trained_run, tmp_path):
    """The sample meshes' chairs rendered as category ``lamp`` (``--category``), all in test:
    the shared run trained on no lamp, and ``eval`` said nothing (no note, ``trained_on`` 0, the
    mean over categories of lamp alone); now a note and ``categories_not_trained_on``."""
    import json

    from sc3d_cli.data import main as data_main
    from tests.conftest import SAMPLE_MESHES

    shards = tmp_path / "lamps"
    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES / "chair", "--out", shards, "--category", "lamp",
                        "--split", "random:0,0,1", "--voxelize", "--views", 4, "--workers", 1, "--no-progress"])
    res = run_cli(main, ["eval", "--checkpoint", trained_run / "checkpoints" / "last.pt", "--shards", shards,
                         "--split", "test", "--out", tmp_path / "ev", "--examples", 0])
    assert ("note: the checkpoint's run had no training object of lamp (03636649): their figures, and the mean over "
            "categories, measure the model on categories it never saw") in res.output, res.output
    metrics = json.loads((tmp_path / "ev" / "metrics.json").read_text())
    assert metrics["categories_not_trained_on"] == ["03636649"] and metrics["trained_on"] == 0  # lamp's synset
