"""``sc3d-train eval`` and ``claims``, round seven: what an evaluation claims about the objects
it measured. E1: shards re-rendered in place with another split made ``eval`` count trained-on
objects against the new split; E2: ``claims`` reused evaluations of eval shards re-rendered in
place; E3: the split that chose ``best.pt`` passed as a held-out split; E4: ``--pick`` with a
checkpoint file, and a ``checkpoints`` folder; E5: a huge ``--batch-size``; E6: a huge
``claims --seeds`` and an unknown ``--device``. Real shards, real tiny trainings, no mocks."""
from __future__ import annotations

import json
import shutil

from sc3d_cli.data import main as data_main
from sc3d_cli.train import main as train_main
from conftest import SAMPLE_MESHES, run_cli
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
