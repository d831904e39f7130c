"""claims.md's tables (``claims_report.format_report``) on a user's categories, from results made
by hand (no training): each category keeps its own column header, whole, as claims.png names it."""
from __future__ import annotations


def _results(cats: list[str]) -> dict:
    """One run (one seed) with IoU@0.4 0.1, 0.2, ... per category in ``cats``' order."""
    per_category = {c: {"voxel_iou_0.4": 0.1 * (k + 1), "pose_rotation_median": 10.0, "pose_rotation_acc30": 0.5}
                    for k, c in enumerate(cats)}
    return {"sup-3tube": {"seeds": [0], "per_category": per_category, "overall": {},
                          "mean": {"voxel_iou_0.4": 0.25, "pose_rotation_median": 10.0, "pose_rotation_acc30": 0.5}}}


def test_claims_table_names_categories_whole_as_the_picture_does():
    """``chair (metal)`` and ``chair (wood)`` were both headed ``chair`` (the name cut at its first
    `` (``, meant for ``airplane (02691156)``): two columns of one name, while claims.png named them
    whole. A synset id is still headed by its name."""
    from sc3d_train.evaluation.claims_report import format_report

    text = format_report(_results(["02691156", "chair (metal)", "chair (wood)"]))
    assert "| run | airplane | chair (metal) | chair (wood) | Mean |\n" in text
    assert "| Ours (Sup), 3 tubes | 10.0 | 20.0 | 30.0 | 25.0 |\n" in text


def test_claims_table_escapes_a_bar_in_a_category_name():
    """A category folder ``desk|lamp`` split its header cell in two: the header had one column more
    than the separator and the rows, so the table was no table."""
    from sc3d_train.evaluation.claims_report import format_report

    text = format_report(_results(["02958343", "desk|lamp"]))
    assert "| run | car | desk\\|lamp | Mean |\n|---|---|---|---|\n" in text
    lines = text.splitlines()
    for head, rule in zip(lines, lines[1:]):
        if head.startswith("| run |"):  # both tables: as many cells as the separator below
            assert len(head.replace("\\|", "").split("|")) == len(rule.split("|")), head
