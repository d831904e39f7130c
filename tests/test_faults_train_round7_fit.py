"""Hostile inputs to `sc3d-train fit` and the shard index, round seven: a torch kept by
setup.sh that is too old to load checkpoints safely, elevations outside the pose grid, malformed
or newer indexes, resume messages. Real CLI, real HDF5, real tiny runs; expected outcomes are
stated by hand."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import REPO, run_cli

QUICK = ["--tiny", "--steps", "2", "--batch-size", "2", "--val-every", "0", "--no-progress"]


@pytest.fixture(scope="module")
def tiny_run(sample_shards, tmp_path_factory):
    from sc3d_cli.train import main as train_main

    out = tmp_path_factory.mktemp("r7fit") / "run"
    run_cli(train_main, ["fit", "--shards", sample_shards, "--out", out, *QUICK])
    return out


def one_line(output: str) -> str:
    return " ".join(output.split())


def setup_torch_ok(tmp_path: Path, version: str) -> bool:
    """What scripts/setup.sh's ``torch_ok`` says of a python whose torch reports ``version`` (a
    stand-in torch package: only its ``__version__`` is read)."""
    fake = tmp_path / version / "torch"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text(f"__version__ = {version!r}\n")
    script = (REPO / "scripts" / "setup.sh").read_text()
    func = script[script.index("torch_ok() {"):]
    func = func[:func.index("\n}\n") + 3]
    env = {**os.environ, "PYTHONPATH": str(fake.parent)}
    res = subprocess.run(["bash", "-c", f'{func}\ntorch_ok "$0"', sys.executable], cwd=REPO, env=env)
    return res.returncode == 0


@pytest.mark.parametrize("version, ok", [("2.5.1+cu121", False), ("2.4.0", False), ("2.6.0", True),
                                         ("2.13.0+cpu", True)])
def test_r7_setup_keeps_no_torch_older_than_2_6(tmp_path, version, ok):
    """setup.sh --gpu kept whatever CUDA torch the system python had (and an existing .venv's
    torch), though torch <= 2.5.1 runs code from a crafted checkpoint (CVE-2025-32434)."""
    assert setup_torch_ok(tmp_path, version) is ok


@pytest.fixture(scope="module")
def steep_shards(tmp_path_factory):
    """Two sample chairs rendered at elevations 0 and 60 deg (the default pose grid is [10, 50])."""
    from sc3d_cli.data import main as data_main

    from conftest import SAMPLE_MESHES

    out = tmp_path_factory.mktemp("steep") / "shards"
    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES / "chair", "--out", out, "--voxelize", "--elevations",
                        "0,60", "--views", "4", "--split", "random:0.5,0.5,0", "--no-progress"])
    return out


def test_r7_fit_warns_of_elevations_outside_the_pose_grid_and_eval_does_not_call_them_other_data(
        steep_shards, tmp_path):
    """fit trained silently on views its pose grid cannot represent, and eval of the very shards it
    trained on then said they 'differ from the checkpoint's training data'. Now fit warns before
    training, naming the elevations, the grid and the config keys; eval notes the grid alone."""
    from sc3d_cli.train import main as train_main

    run = tmp_path / "run"
    res = run_cli(train_main, ["fit", "--shards", steep_shards, "--out", run, "--tiny", "--steps", "2",
                               "--batch-size", "2", "--val-every", "0", "--no-progress"])
    warning = [ln for ln in res.output.splitlines() if ln.startswith("warning:")]
    assert len(warning) == 1, res.output
    assert "elevations [0.0, 60.0] deg lie outside the pose grid [10, 50]" in warning[0]
    assert "model.elevation_min" in warning[0] and "model.elevation_max" in warning[0]
    assert res.output.index("warning:") < res.output.index("done:")
    res = run_cli(train_main, ["eval", "--checkpoint", run, "--shards", steep_shards, "--split", "val",
                               "--out", tmp_path / "ev"])
    notes = [ln for ln in res.output.splitlines() if ln.startswith("note:")]
    assert not any("differ" in n for n in notes), res.output
    assert any("elevations [0.0, 60.0] deg of these shards lie outside the checkpoint's pose grid [10, 50]" in n
               for n in notes), res.output
    metrics = json.loads((tmp_path / "ev" / "metrics.json").read_text())
    assert metrics["differs_from_training"] == [] and metrics["outside_pose_grid"] == [0.0, 60.0]


def test_r7_fit_says_nothing_of_elevations_inside_the_grid(sample_shards, tmp_path):
    from sc3d_cli.train import main as train_main

    res = run_cli(train_main, ["fit", "--shards", sample_shards, "--out", tmp_path / "run", *QUICK])
    assert "warning:" not in res.output and "pose grid" not in res.output


def _edited_copy(shards: Path, dest: Path, edit) -> Path:
    """A copy of ``shards`` whose parsed index.json ``edit`` changed in place."""
    shutil.copytree(shards, dest)
    index = json.loads((dest / "index.json").read_text())
    edit(index)
    (dest / "index.json").write_text(json.dumps(index))
    return dest


@pytest.mark.parametrize("edit, says", [
    (lambda i: i.update(failures=[5]), "failures[0] is 5, not an object"),
    (lambda i: i.update(warnings=["look"]), "warnings[0] is 'look', not an object"),
    (lambda i: i.update(skipped={"a": 1}), "skipped is dict, not a list"),
    (lambda i: i["settings"].update(background="x"), "settings.background is 'x', not a number or a list of 3"),
    (lambda i: i["settings"].update(elevations=30), "settings.elevations is 30, not a list of numbers"),
    (lambda i: i["settings"].update(image_size="64"), "settings.image_size is '64', not an integer"),
    (lambda i: i.update(settings=[]), "settings is list, not an object"),
])
def test_r7_a_malformed_index_is_refused_in_one_line_naming_the_key(sample_shards, tmp_path, edit, says):
    """A failures entry that is no object gave AttributeError tracebacks (fit, sc3d-data info);
    a string background 'could not convert string to float' naming neither file nor key."""
    from sc3d_cli.data import main as data_main
    from sc3d_cli.train import main as train_main

    bad = _edited_copy(sample_shards, tmp_path / "bad", edit)
    for group, args in ((train_main, ["fit", "--shards", bad, "--out", tmp_path / "run", *QUICK]),
                        (data_main, ["info", bad])):
        res = run_cli(group, args, expect_exit=1)
        assert "Traceback" not in res.output and res.output.startswith("Error:"), res.output
        assert f"{bad / 'index.json'}: malformed: {says}" in one_line(res.output), res.output
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("version, says", [
    (99, "schema_version 99 is newer than the 1 this sc3d reads (written by a newer sc3d): upgrade sc3d"),
    ("1", "malformed: schema_version is '1', not an integer"),
    (None, "malformed: no schema_version"),
])
def test_r7_an_index_of_another_schema_version_is_refused(sample_shards, tiny_run, tmp_path, version, says):
    """schema_version was written and never read: an index of schema 99 was evaluated as if it
    were this one. SCHEMA_VERSION is 1 (sc3d_data.io.shards)."""
    from sc3d_cli.train import main as train_main

    def edit(index):
        if version is None:
            del index["schema_version"]
        else:
            index["schema_version"] = version

    other = _edited_copy(sample_shards, tmp_path / "other", edit)
    res = run_cli(train_main, ["eval", "--checkpoint", tiny_run, "--shards", other, "--out", tmp_path / "ev"],
                  expect_exit=1)
    assert f"{other / 'index.json'}: {says}" in one_line(res.output), res.output
    assert not (tmp_path / "ev" / "metrics.json").exists()


def test_r7_a_shard_file_of_a_newer_schema_is_refused(sample_shards, tiny_run, tmp_path):
    """The shard's own HDF5 schema_version attribute is checked as the index's is; control: the
    unedited copy evaluates."""
    import h5py

    from sc3d_cli.train import main as train_main

    other = _edited_copy(sample_shards, tmp_path / "other", lambda i: None)
    run_cli(train_main, ["eval", "--checkpoint", tiny_run, "--shards", other, "--out", tmp_path / "ok"])
    shard = sorted(other.glob("shard-*.h5"))[0]
    with h5py.File(shard, "r+") as f:
        f.attrs["schema_version"] = 99
    res = run_cli(train_main, ["eval", "--checkpoint", tiny_run, "--shards", other, "--out", tmp_path / "ev"],
                  expect_exit=1)
    assert f"{shard}: schema_version 99 is newer than the 1 this sc3d reads" in one_line(res.output), res.output


def test_r7_resume_of_a_run_already_at_its_steps_says_so(sample_shards, tmp_path):
    """`fit --resume --steps 4` of a 6-step run printed 'done: step 6, 0.0 samples/s; ' with an
    empty loss list; now one line says nothing is trained and why, and no 'training ... for 4
    steps' line comes before it (found by fix_small)."""
    from sc3d_cli.train import main as train_main

    run = tmp_path / "run"
    run_cli(train_main, ["fit", "--shards", sample_shards, "--out", run, *QUICK, "--steps", "6"])
    res = run_cli(train_main, ["fit", "--out", run, "--resume", "--steps", "4", "--no-progress"])
    assert "done:" not in res.output and "samples/s" not in res.output
    # it said 'training supervised for 4 steps, ...' first, then that nothing was trained
    assert "training " not in res.output, res.output
    assert f"nothing to train: {run / 'checkpoints' / 'last.pt'} is already at step 6 >= --steps 4" \
        in one_line(res.output), res.output


def test_r7_resume_says_which_checkpoint_it_falls_back_to_and_why(sample_shards, tmp_path):
    """A truncated last.pt made --resume fall back to step_000002.pt silently and train those
    steps again; now one line names the file it resumes from and why."""
    from sc3d_cli.train import main as train_main

    run = tmp_path / "run"
    run_cli(train_main, ["fit", "--shards", sample_shards, "--out", run, *QUICK, "--checkpoint-every", "2",
                         "--steps", "4"])
    last = run / "checkpoints" / "last.pt"
    last.write_bytes(last.read_bytes()[:200])
    res = run_cli(train_main, ["fit", "--out", run, "--resume", "--steps", "6", "--no-progress"])
    line = [ln for ln in res.output.splitlines() if ln.startswith("resuming from")]
    assert len(line) == 1, res.output
    assert line[0].startswith(f"resuming from {run / 'checkpoints' / 'step_000004.pt'} (step 4): last.pt unreadable: "
                              f"{last}: ")
    assert "done: step 6" in res.output


def test_r7_an_unknown_val_split_is_refused(sample_shards, tmp_path):
    """`--val-split valid` (a typo) printed a note and trained the whole run without validation
    or best.pt; split names are train, val and test."""
    from sc3d_cli.train import main as train_main

    res = run_cli(train_main, ["fit", "--shards", sample_shards, "--out", tmp_path / "run", *QUICK[:5],
                               "--val-split", "valid", "--no-progress"], expect_exit=2)
    assert "'valid' is not one of 'train', 'val', 'test'" in one_line(res.output), res.output
    assert not (tmp_path / "run").exists()
