"""Shared fixtures: the bundled sample meshes rendered and voxelized once per test session
with the real renderer and voxelizer (through the CLI, as a user would)."""
from __future__ import annotations

import os
from pathlib import Path

import pytest
from click.testing import CliRunner

REPO = Path(__file__).resolve().parents[1]
SAMPLE_MESHES = REPO / "assets" / "sample_meshes"

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")


def run_cli(group, args: list[str], expect_exit: int | None = 0):
    """Invoke a click group in-process; fail with the command's output when the exit code differs."""
    result = CliRunner().invoke(group, [str(a) for a in args], catch_exceptions=False)
    if expect_exit is not None and result.exit_code != expect_exit:
        raise AssertionError(f"{args} exited {result.exit_code}, expected {expect_exit}:\n{result.output}")
    return result


@pytest.fixture(scope="session")
def sample_shards(tmp_path_factory) -> Path:
    """Shards of the 11 bundled sample meshes: 24 views of 64x64, masks, cameras and 32^3 voxels,
    default split (seeded 70/10/20 by object)."""
    from cli.data import main

    out = tmp_path_factory.mktemp("sample_shards")
    run_cli(main, ["render", "--meshes", SAMPLE_MESHES, "--out", out, "--voxelize", "--workers", "2"])
    return out
