"""Category names from disk in the reports of ``sc3d-train``: ``eval``'s table (printed) and
``claims.md`` (a markdown table, also printed) escape control characters as ``info`` and ``check``
do (``io.names.printable``; docs/data.md, "Names"), so a folder named with a newline or an escape
sequence neither splits a table row nor reaches the terminal."""
from __future__ import annotations

NAMES = ["new\nline", "esc\x1b[2Jx"]


def test_eval_table_escapes_control_characters_in_category_names():
    """A category folder ``new\\nline`` split its row of the table in two (the figures on a line
    of their own, under no name), and ``esc\\x1b[2Jx`` cleared the terminal eval printed it to."""
    from sc3d_train.evaluation.evaluate import format_table

    vals = {"voxel_iou_0.4": 0.1}
    table = format_table({"per_category": {n: vals for n in NAMES}, "mean": vals, "overall": vals})
    assert "\x1b" not in table
    lines = table.splitlines()
    assert len(lines) == 1 + len(NAMES) + 2, lines
    assert lines[1].startswith("new\\nline ") and lines[2].startswith("esc\\x1b[2Jx ")


def test_claims_tables_escape_control_characters_in_category_names():
    """A newline in a category's column header cut the header row of claims.md's tables in two:
    the markdown was no table (and the escape sequence went to the terminal with the printed report)."""
    from sc3d_train.evaluation.claims_report import format_report

    per_category = {c: {"voxel_iou_0.4": 0.2, "pose_rotation_median": 10.0, "pose_rotation_acc30": 0.5}
                    for c in NAMES}
    text = format_report({"sup-3tube": {"seeds": [0], "per_category": per_category, "overall": {},
                                        "mean": {"voxel_iou_0.4": 0.2, "pose_rotation_median": 10.0,
                                                 "pose_rotation_acc30": 0.5}}})
    assert "\x1b" not in text
    assert "| run | esc\\x1b[2Jx | new\\nline | Mean |\n|---|---|---|---|\n" in text


def test_training_note_on_left_out_objects_escapes_their_names(tmp_path, capsys):
    """``fit``'s note naming objects whose voxelization failed printed a category folder
    ``esc\\x1b[2Jx`` as it is: the escape sequence reached the terminal."""
    from conftest import run_cli
    from sc3d_cli.data import main as data_main
    from test_faults import CUBE_F, CUBE_V, FAST, obj_text
    from sc3d_train.data.dataset import scan_objects

    meshes, shards = tmp_path / "m", tmp_path / "s"
    (meshes / NAMES[1]).mkdir(parents=True)
    for name in "ab":
        (meshes / NAMES[1] / f"{name}.obj").write_text(obj_text(CUBE_V, CUBE_F))
    run_cli(data_main, ["render", "--meshes", meshes, "--out", shards, *FAST])
    (meshes / NAMES[1] / "a.obj").rename(tmp_path / "gone.obj")
    run_cli(data_main, ["voxelize", shards, "--no-progress"])
    capsys.readouterr()
    scan_objects(shards)
    err = capsys.readouterr().err
    assert "\x1b" not in err and err.rstrip().endswith("(index.json failures): esc\\x1b[2Jx/a"), err
