"""``sc3d-train eval`` and ``claims``, round seven: what an evaluation claims about the objects
it measured. E1: shards re-rendered in place with another split made ``eval`` count trained-on
objects against the new split; E2: ``claims`` reused evaluations of eval shards re-rendered in
place; E3: the split that chose ``best.pt`` passed as a held-out split; E4: ``--pick`` with a
checkpoint file, and a ``checkpoints`` folder; E5: a huge ``--batch-size``; E6: a huge
``claims --seeds`` and an unknown ``--device``. Real shards, real tiny trainings, no mocks."""
from __future__ import annotations

import json
import shutil

import pytest

from sc3d_cli.data import main as data_main
from sc3d_cli.train import main as train_main
from conftest import SAMPLE_MESHES, run_cli, error_lines
from tests.test_train import TINY


def _fit(shards, out, *extra):
    """A 2-step tiny run on ``shards`` (validation off unless ``extra`` turns it on)."""
    run_cli(train_main, ["fit", "--shards", shards, "--out", out, "--steps", 2, "--batch-size", 2, *TINY,
                         "--val-every", 0, "--device", "cpu", *extra])


def _eval(run, shards, split, out, *extra, expect_exit=0):
    """``eval --pose head`` on the CPU: (output, metrics.json or None)."""
    res = run_cli(train_main, ["eval", "--checkpoint", run, "--shards", shards, "--split", split, "--pose", "head",
                               "--device", "cpu", "--out", out, "--examples", 0, *extra], expect_exit=expect_exit)
    metrics = out / "metrics.json"
    return res.output, (json.loads(metrics.read_text()) if metrics.is_file() else None)


@pytest.fixture(scope="module")
def val_run(sample_shards, tmp_path_factory):
    """A 4-step tiny run validated after steps 2 and 4 on the 2 'val' objects of the sample
    shards: ``checkpoints/best.pt`` (chosen on them) and ``last.pt`` (step 4)."""
    run = tmp_path_factory.mktemp("val_run") / "run"
    _fit(sample_shards, run, "--steps", 4, "--val-every", 2, "--val-min-objects", 1)
    assert (run / "checkpoints" / "best.pt").is_file()
    return run


# ----------------------------------------------------------------------------- E1
def test_e1_eval_does_not_count_trained_objects_against_a_new_split(sample_shards, tmp_path):
    """A run trained on shards that were then re-rendered in place with every object in 'test'
    (``--split random:0,0,1``): its training objects are now test objects. ``eval --split test``
    counted them against the shards' new 'train' split (none) and said nothing; the shards no
    longer match the run's ``objects_sha256``, so whether they were trained on is unknown:
    ``trained_on`` null and the note."""
    shards = tmp_path / "shards"
    shutil.copytree(sample_shards, shards)
    run = tmp_path / "run"
    _fit(shards, run)
    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES, "--out", shards, "--voxelize", "--no-progress",
                        "--views", 2, "--split", "random:0,0,1", "--overwrite"])
    output, metrics = _eval(run, shards, "test", tmp_path / "eval")
    assert metrics["overall"]["objects"] == 11
    assert metrics["trained_on"] is None, metrics["trained_on"]
    assert "whether evaluated objects were trained on is unknown" in output


# ----------------------------------------------------------------------------- E2
def test_e2_claims_redoes_evaluations_of_eval_shards_rerendered_in_place(sample_shards, tmp_path):
    """A claims study reran after its eval shards were re-rendered in place (black background,
    2 views) read its old ``metrics.json`` back ("done before"), reporting figures of data that
    no longer exists. ``eval`` now records ``data_sha256`` and a rerun redoes an evaluation whose
    digest differs (here: the new figures count 2 views per object, not 24), and one without a
    digest (an earlier version's); an unchanged rerun still reuses it."""
    from sc3d_train.evaluation.claims import ClaimsPreset, run_all

    eval_shards = tmp_path / "eval_shards"
    shutil.copytree(sample_shards, eval_shards)
    preset = ClaimsPreset(steps=2, batch_size=2, lr=1e-3, tiny=True, runs=("sup-3tube",),
                          extra={"val_every": 0, "base_channels": 4})
    out = tmp_path / "claims"

    def study():
        said = []
        run_all(sample_shards, eval_shards, out, preset, "test", "cpu", 0, echo=said.append)
        return said, json.loads((out / "runs" / "sup-3tube" / "seed-0" / "eval" / "metrics.json").read_text())

    said, first = study()
    test_objects = first["overall"]["objects"]
    assert first["overall"]["images"] == 24 * test_objects
    said, again = study()
    assert any("done before" in s for s in said) and again == first
    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES, "--out", eval_shards, "--voxelize", "--no-progress",
                        "--views", 2, "--background", "0,0,0", "--overwrite"])
    said, redone = study()
    assert not any("done before" in s for s in said), said
    assert redone["overall"]["images"] == 2 * test_objects
    assert redone["data_sha256"] != first["data_sha256"]
    metrics = out / "runs" / "sup-3tube" / "seed-0" / "eval" / "metrics.json"
    old = json.loads(metrics.read_text())
    del old["data_sha256"]                      # as an earlier version wrote it
    metrics.write_text(json.dumps(old))
    said, _ = study()
    assert not any("done before" in s for s in said), said


# ----------------------------------------------------------------------------- E3
def test_e3_eval_of_best_pt_on_the_split_that_chose_it_says_so(sample_shards, val_run, tmp_path):
    """``best.pt`` is the best of the run's validations on its 'val' objects (here 2 of the sample
    shards, validated after steps 2 and 4); evaluating it on those objects gave figures that read
    as held-out with no note. Now a note and ``selected_on_this_split: true``; the test split, and
    ``last.pt`` (nothing chose it) on 'val', are not flagged."""
    run = val_run
    output, metrics = _eval(run, sample_shards, "val", tmp_path / "val")
    assert metrics["selected_on_this_split"] is True and metrics["trained_on"] == 0
    assert "so these figures are optimistic; evaluate on --split test or with --pick last" in output
    output, metrics = _eval(run, sample_shards, "test", tmp_path / "test")
    assert metrics["selected_on_this_split"] is False and "optimistic" not in output
    output, metrics = _eval(run, sample_shards, "val", tmp_path / "val-last", "--pick", "last")
    assert metrics["selected_on_this_split"] is False and "optimistic" not in output


def test_e3_claims_refuses_to_evaluate_on_the_split_that_chooses_best_pt(sample_shards, tmp_path):
    """``claims --eval-split val`` on the training shards, with validation on: each run's best.pt
    would be evaluated on the objects that chose it. Refused before any training, in one line
    naming the split and the way out."""
    from sc3d_train.data.dataset import DataError
    from sc3d_train.evaluation.claims import ClaimsPreset, run_all

    preset = ClaimsPreset(steps=2, batch_size=2, lr=1e-3, tiny=True, runs=("sup-3tube",),
                          extra={"val_every": 1, "val_min_objects": 1, "base_channels": 4})
    out = tmp_path / "claims"
    with pytest.raises(DataError, match=r"2 object\(s\) of split 'val' are the 'val' objects of .* that choose each "
                                        r"run's best.pt .*--pick last"):
        run_all(sample_shards, sample_shards, out, preset, "val", "cpu", 0, echo=lambda s: None)
    assert not (out / "runs").exists()


# ----------------------------------------------------------------------------- E4
def test_e4_pick_with_a_checkpoint_file_is_refused_and_a_checkpoints_folder_is_its_run(sample_shards, val_run,
                                                                                       tmp_path):
    """``--pick last`` with ``--checkpoint RUN/checkpoints/best.pt`` evaluated best.pt, ignoring
    the option: now refused in one line naming the run folder to give instead (eval and predict).
    ``--checkpoint RUN/checkpoints`` looked for ``RUN/checkpoints/checkpoints/last.pt``: it now
    stands for RUN (``--pick last``: last.pt, step 4), and a file without ``--pick`` is read as it is."""
    from PIL import Image

    best, folder = val_run / "checkpoints" / "best.pt", val_run / "checkpoints"
    output, metrics = _eval(best, sample_shards, "test", tmp_path / "refused", "--pick", "last", expect_exit=1)
    errors = error_lines(output)
    assert errors == [f"Error: --pick last: {best} is a checkpoint file, and --pick chooses a checkpoint of a run "
                      f"folder; give the run folder (--checkpoint {val_run} --pick last) or leave --pick out"], output
    assert metrics is None
    _, metrics = _eval(folder, sample_shards, "test", tmp_path / "folder", "--pick", "last")
    assert metrics["checkpoint"] == str(folder / "last.pt") and metrics["step"] == 4
    _, metrics = _eval(best, sample_shards, "test", tmp_path / "file")
    assert metrics["checkpoint"] == str(best)
    image = tmp_path / "white.png"
    Image.new("RGB", (64, 64), (255, 255, 255)).save(image)
    res = run_cli(train_main, ["predict", "--checkpoint", best, "--pick", "best", image, "--out", tmp_path / "p1",
                               "--device", "cpu"], expect_exit=1)
    assert error_lines(res.output)[0].startswith(
        f"Error: --pick best: {best} is a checkpoint file"), res.output
    run_cli(train_main, ["predict", "--checkpoint", folder, image, "--out", tmp_path / "p2", "--device", "cpu",
                         "--pose", "head"])
    assert (tmp_path / "p2" / "white.json").is_file()


# ----------------------------------------------------------------------------- E5
def test_e5_a_huge_batch_size_is_refused_in_one_line_naming_the_option(sample_shards, val_run, tmp_path):
    """``eval --batch-size 99999999999999999999`` failed with islice's message (no option named);
    ``fit`` with it would build index lists on a GPU until memory ran out. Both now refuse any
    batch above 2^24 = 16777216 in one line naming --batch-size, before any work; 2^24 itself
    is accepted (the whole split in one batch)."""
    huge = 99999999999999999999
    expected = (f"Error: batch_size (--batch-size) must be at most 16777216 (2^24 images of 64x64 RGB are 200 GB "
                f"even as bytes), got {huge}")
    output, metrics = _eval(val_run, sample_shards, "test", tmp_path / "huge", "--batch-size", huge, expect_exit=1)
    assert error_lines(output) == [expected], output
    assert "Traceback" not in output and metrics is None and not (tmp_path / "huge").exists()
    _, metrics = _eval(val_run, sample_shards, "test", tmp_path / "max", "--batch-size", 2 ** 24)
    assert metrics["overall"]["images"] == 24 * metrics["overall"]["objects"]
    res = run_cli(train_main, ["fit", "--shards", sample_shards, "--out", tmp_path / "run", "--steps", 2,
                               "--batch-size", huge, *TINY, "--device", "cpu"], expect_exit=1)
    assert error_lines(res.output) == [expected], res.output
    assert not (tmp_path / "run" / "checkpoints").exists()


# ----------------------------------------------------------------------------- E6
@pytest.mark.parametrize("seeds", [101, 100000000000])
def test_e6_claims_refuses_too_many_seeds_before_anything(sample_shards, tmp_path, seeds):
    """``claims --seeds 100000000000`` built the list of seeds until memory ran out (MemoryError
    under a limit, the machine's memory without); 101 would start a study of weeks. Above 100
    it is refused in one line naming --seeds and why, before the study folder is created (and
    before the device, bogus here, is looked at)."""
    out = tmp_path / "claims"
    res = run_cli(train_main, ["claims", "--train-shards", sample_shards, "--eval-shards", sample_shards, "--out", out,
                               "--runs", "sup-3tube", "--seeds", seeds, "--device", "bogus"], expect_exit=1)
    assert res.output.splitlines() == [
        f"Error: seeds (--seeds) must be in [1, 100], got {seeds} (each seed trains and evaluates every run again: "
        f"100 is already days of computing)"], res.output
    assert not out.exists()


def test_e6_claims_refuses_an_unknown_device_before_training(sample_shards, tmp_path):
    """``claims --device bogus`` was refused only by the first run's ``fit``, after its
    "training" line. Now one line and nothing else, no study folder."""
    out = tmp_path / "claims"
    res = run_cli(train_main, ["claims", "--train-shards", sample_shards, "--eval-shards", sample_shards, "--out", out,
                               "--runs", "sup-3tube", "--device", "bogus"], expect_exit=1)
    assert res.output.splitlines() == [
        "Error: --device 'bogus': not a device; use auto (CUDA if present), cpu, cuda or cuda:N."], res.output
    assert not out.exists()
