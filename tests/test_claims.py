"""sc3d-train claims: every run of the study is trained and evaluated, the report has the paper's
tables, and a rerun resumes instead of retraining."""
from __future__ import annotations

import json

import yaml

from sc3d_cli.train import main
from tests.conftest import run_cli


def test_claims_trains_every_run_and_writes_the_tables(sample_shards, tmp_path):
    from sc3d_train.claims import RUNS, ClaimsPreset, run_all

    preset = ClaimsPreset(steps=2, batch_size=4, lr=1e-3, tiny=True)
    out = tmp_path / "claims"
    lines = []
    results = run_all(sample_shards, sample_shards, out, preset, eval_split="test", device="cpu", echo=lines.append)
    assert set(results) == set(RUNS)
    for name in RUNS:
        cfg = yaml.safe_load((out / "runs" / name / "config.yaml").read_text())
        assert cfg["steps"] == 2 and cfg["seed"] == 0  # equal budgets, one seed
        assert (out / "runs" / name / "eval" / "metrics.json").is_file()
    modes = {n: yaml.safe_load((out / "runs" / n / "config.yaml").read_text()) for n in RUNS}
    assert modes["sup-1tube"]["model"]["voxel_decoder"] == "1tube"
    assert modes["semi"]["mode"] == "semi" and modes["labeled-only"]["mode"] == "labeled-only"
    assert modes["ray"]["loss_weights"]["proj"] == 0.0 and modes["ray-proj"]["loss_weights"]["proj"] == 0.125
    report = (out / "claims.md").read_text()
    for title in ("Ours (Sup), 3 tubes", "Ours (Sup), 1 tube", "labelled only", "Ours (Semi)",
                  "Ray (true pose)", "Ray + Projection (true pose)", "| claim | measured | holds |"):
        assert title in report, title
    saved = json.loads((out / "claims.json").read_text())
    assert saved["results"]["semi"]["mean"]["voxel_iou_0.4"] == results["semi"]["mean"]["voxel_iou_0.4"]
    assert (out / "claims.png").stat().st_size > 10_000
    # a rerun trains nothing: every run is read back
    again = []
    run_all(sample_shards, sample_shards, out, preset, eval_split="test", device="cpu", echo=again.append)
    assert sum("done before" in line for line in again) == len(RUNS)


def test_claims_cli_refuses_unknown_runs(sample_shards, tmp_path):
    r = run_cli(main, ["claims", "--train-shards", sample_shards, "--eval-shards", sample_shards,
                       "--out", tmp_path / "c", "--runs", "sup-3tube,bogus"], expect_exit=2)
    assert "bogus" in r.output
