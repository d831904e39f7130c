"""Defects of the training half noticed by the thirteenth attack and found by the fourteenth
(2026-11-28), each test failing without its fix. Real runs of the tiny model on the bundled
sample meshes."""
from __future__ import annotations

import yaml

from sc3d_cli.train import main
from tests.conftest import run_cli
from tests.test_train import TINY
from conftest import error_lines


# ----------------------------------------------------------------------------- --resume --amp off
def test_resume_accepts_precision_settings_that_are_the_runs_own_on_this_device(sample_shards, tmp_path):
    """A run started with the defaults (``amp: auto``, ``channels_last: auto``) on the CPU trains
    in fp32 and NCHW; ``--resume --amp off --channels-last off`` asks for exactly that and was
    refused as a change. The control: ``--amp bf16`` would change the precision and stays refused."""
    out = tmp_path / "run"
    run_cli(main, ["fit", "--shards", sample_shards, "--out", out, "--steps", 2, "--batch-size", 4, *TINY,
                   "--val-every", 0, "--device", "cpu", "--no-progress"])
    run_cli(main, ["fit", "--out", out, "--resume", "--steps", 3, "--amp", "off", "--channels-last", "off",
                   "--device", "cpu", "--no-progress"])
    saved = yaml.safe_load((out / "config.yaml").read_text())
    assert (saved["amp"], saved["channels_last"], saved["steps"]) == ("auto", "auto", 3)
    res = run_cli(main, ["fit", "--out", out, "--resume", "--steps", 4, "--amp", "bf16", "--device", "cpu",
                         "--no-progress"], expect_exit=1)
    assert error_lines(res.output) == [f"Error: {out}: cannot change on --resume: --amp 'bf16' (run has 'auto')"]
