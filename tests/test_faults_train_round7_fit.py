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
