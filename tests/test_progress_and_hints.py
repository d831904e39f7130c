"""User-facing gaps found by trying the toolkit (issue 10): progress output in logs, the
`--split` rules in `--help`, and the hint for shards without voxels."""
from __future__ import annotations

import io
import re
import shlex
import shutil

import pytest

from sc3d_cli.data import main
from conftest import SAMPLE_MESHES, run_cli
from sc3d_data.pipeline.run.progress import LineProgress, progress_bar


class FakeTTY(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_in_a_log_prints_a_line_per_ten_percent():
    log = io.StringIO()
    bar = progress_bar(total=1000, unit="obj", desc="render", file=log)
    assert isinstance(bar, LineProgress)
    for _ in range(1000):
        bar.update(1)
    bar.close()
    text = log.getvalue()
    assert "\r" not in text
    lines = text.splitlines()
    assert 10 <= len(lines) <= 11                      # 10%, 20%, ... 100% (+ the closing line)
    assert lines[0].startswith("render: 100/1000 (10%)") and "obj/s" in lines[0]
    assert lines[-1].startswith("render: 1000/1000 (100%)")


def test_progress_without_total_prints_per_interval_and_wraps_iterables():
    log = io.StringIO()
    items = list(LineProgress(iter(range(5)), unit="obj", desc="check", file=log, every_s=0.0))
    assert items == [0, 1, 2, 3, 4]
    lines = log.getvalue().splitlines()
    assert lines[0].startswith("check: 1 obj in 0:00:00") and lines[-1].startswith("check: 5 obj")


def test_progress_on_a_terminal_is_a_tqdm_bar():
    from tqdm import tqdm

    bar = progress_bar(total=3, file=FakeTTY())
    assert isinstance(bar, tqdm)
    bar.close()


def test_render_progress_in_captured_output_is_plain_lines(tmp_path):
    (tmp_path / "m" / "chair").mkdir(parents=True)
    shutil.copy(SAMPLE_MESHES / "chair" / "chair2_blendswap.glb", tmp_path / "m" / "chair")
    res = run_cli(main, ["render", "--meshes", tmp_path / "m", "--out", tmp_path / "out", "--views", "4",
                         "--workers", "1"])                                      # progress on (default)
    assert "\r" not in res.output
    assert re.search(r"^render: 1/1 \(100%\)", res.output, re.M), res.output


@pytest.mark.parametrize("command", ["render", "import-r2n2"])
def test_split_rules_in_help(command):
    out = run_cli(main, [command, "--help"]).output
    flat = " ".join(out.split())
    for needle in ("random:TRAIN,VAL,TEST", "random:1,0,0", "r2n2: per category", "80% train",
                   "--split-file overrides --split", "SYNSET_{train,val,test}ids.txt"):
        assert needle in flat, (command, needle)


def test_missing_voxels_hint_names_a_command_that_works(tmp_path):
    from sc3d_train.data.dataset import DataError, ShardDataset

    (tmp_path / "m" / "chair").mkdir(parents=True)
    shutil.copy(SAMPLE_MESHES / "chair" / "chair2_blendswap.glb", tmp_path / "m" / "chair")
    out = tmp_path / "out"
    run_cli(main, ["render", "--meshes", tmp_path / "m", "--out", out, "--views", "4", "--workers", "1",
                   "--split", "random:1,0,0", "--no-progress"])
    with pytest.raises(DataError) as e:
        ShardDataset(out, split="train")
    hint = re.search(r"`sc3d-data ([^`]+)`", str(e.value))
    assert hint, str(e.value)
    run_cli(main, shlex.split(hint.group(1)) + ["--no-progress"])               # the hint works as given
    assert len(ShardDataset(out, split="train")) > 0
