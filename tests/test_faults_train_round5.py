"""The fifth attack on ``sc3d-train`` (fit, eval, claims as a user runs them, in areas the earlier
rounds did not reach): one test per finding T1-Tn. Real shards (the bundled sample meshes
rendered through the CLI), real tiny training, evaluation and checkpoints; no mocks."""
from __future__ import annotations

import json
import shutil

import pytest


# ----------------------------------------------------------------------------- T1
def test_t1_claims_redoes_an_evaluation_that_was_cut_short(sample_shards, tmp_path):
    """``evaluate`` wrote ``metrics.json`` first (not atomically) and ``predictions.png`` after it,
    and ``claims`` took any ``eval/metrics.json`` for a finished evaluation. An evaluation whose
    picture could not be written (a full disk; here a folder where the file must go) left
    ``metrics.json`` behind, so the rerun read it back and the study never got the picture; a
    ``metrics.json`` cut short by a kill mid-write made every rerun fail on a JSON error naming no
    file. Now ``metrics.json`` is written last and atomically, and the rerun evaluates again
    whatever was cut short: the figures equal those of the uninterrupted evaluation, byte for
    byte."""
    from sc3d_train.evaluation.claims import ClaimsPreset, run_all

    preset = ClaimsPreset(steps=2, batch_size=4, lr=1e-3, tiny=True, extra={"val_every": 0, "base_channels": 4})
    out = tmp_path / "claims"
    evald = out / "runs" / "sup-3tube" / "seed-0" / "eval"

    def study(echo=None):
        run_all(sample_shards, sample_shards, out, preset, eval_split="test", device="cpu", runs=["sup-3tube"],
                echo=echo or (lambda _: None))

    study()
    whole = (evald / "metrics.json").read_bytes()  # the uninterrupted evaluation

    shutil.rmtree(evald)
    (evald / "predictions.png").mkdir(parents=True)  # the picture's write fails
    with pytest.raises(OSError):
        study()
    assert not (evald / "metrics.json").exists()
    (evald / "predictions.png").rmdir()
    lines = []
    study(lines.append)
    assert not any("done before" in ln for ln in lines), lines
    assert (evald / "predictions.png").is_file() and (evald / "metrics.json").read_bytes() == whole

    (evald / "metrics.json").write_bytes(whole[: len(whole) // 2])  # what a kill mid-write leaves
    study()
    assert (evald / "metrics.json").read_bytes() == whole
    assert json.loads((out / "claims.json").read_text())["meta"]["eval_split"] == "test"
