"""Defects found reviewing the changes of 2026-12-07 (OFF colours, PLY textures, index listing
checks), each test failing without its fix. Files written here by hand; real loader and CLI."""
from __future__ import annotations

import json

from sc3d_cli.data import main as data_main
from conftest import one_error, run_cli
from test_faults import FAST

CUBE = ("OFF\n8 6 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n0 0 1\n1 0 1\n1 1 1\n0 1 1\n"
        "4 0 3 2 1\n4 4 5 6 7\n4 0 1 5 4\n4 1 2 6 5\n4 2 3 7 6\n4 3 0 4 7\n")


def _cubes(root):
    for category in ("a", "b"):
        (root / category).mkdir(parents=True)
        for i in (1, 2):
            (root / category / f"cube{i}.off").write_text(CUBE)
    return root


def test_merge_again_repairs_an_out_index_whose_lists_disagree(tmp_path):
    """A merged OUT whose index lists a shard twice is refused by readers with 'render or merge it
    again', but merging again (also with --overwrite) was refused with that same line: no command
    repaired it. Merging the same parts again now writes a good index."""
    meshes = _cubes(tmp_path / "m")
    parts = [tmp_path / f"p{i}" for i in (0, 1)]
    for i, part in enumerate(parts):
        run_cli(data_main, ["render", "--meshes", meshes, "--out", part, "--part", f"{i}/2", *FAST,
                            "--objects-per-shard", "1", "--image-size", "32"])
    out = tmp_path / "out"
    run_cli(data_main, ["merge", out, *parts])
    index = json.loads((out / "index.json").read_text())
    index["shards"].append(dict(index["shards"][1]))
    (out / "index.json").write_text(json.dumps(index))
    assert "render or merge it again" in one_error(run_cli(data_main, ["info", out], expect_exit=1).output)
    run_cli(data_main, ["merge", out, *parts])
    assert run_cli(data_main, ["info", out, "--verify"]).exit_code == 0
    assert len(json.loads((out / "index.json").read_text())["shards"]) == 4
