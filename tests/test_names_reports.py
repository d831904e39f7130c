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
