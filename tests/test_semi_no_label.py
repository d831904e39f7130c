"""A ``semi`` run with ``--pretrain-steps 0`` and ``--semi-labeled-share 0`` reads no label: its
labelled objects (``labeled_objects.txt``) never enter training. ``fit`` says so in one
``warning:`` line, as it does for a semi run that never reaches its unlabelled phase."""
from __future__ import annotations

from sc3d_cli.train import main
from tests.conftest import run_cli
from tests.test_train import TINY


def semi_fit(sample_shards, out, *extra):
    return run_cli(main, ["fit", "--shards", str(sample_shards), "--out", str(out), *TINY, "--semi",
                          "--labeled-fraction", "0.5", "--steps", "1", "--batch-size", "4",
                          "--val-every", "0", "--device", "cpu", *extra])


def test_a_semi_run_that_reads_no_label_is_warned(sample_shards, tmp_path):
    result = semi_fit(sample_shards, tmp_path / "run", "--pretrain-steps", "0", "--semi-labeled-share", "0")
    lines = [line for line in result.output.splitlines() if line.startswith("warning:")]
    assert len(lines) == 1 and "reads no label" in lines[0] and "labeled_objects.txt" in lines[0], result.output


def test_a_semi_run_with_labels_gets_no_such_warning(sample_shards, tmp_path):
    result = semi_fit(sample_shards, tmp_path / "run", "--pretrain-steps", "0")
    assert "reads no label" not in result.output, result.output
