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
