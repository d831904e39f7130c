"""sc3d-train claims: every run of the study is trained and evaluated, the report has the paper's
tables, and a rerun resumes instead of retraining."""
from __future__ import annotations

import json

import pytest
import yaml

from sc3d_cli.train import main
from tests.conftest import run_cli


def test_claims_trains_every_run_and_writes_the_tables(sample_shards, tmp_path, monkeypatch):
    from sc3d_train.evaluation.claims import RUNS, ClaimsPreset, run_all
    from sc3d_train.evaluation.claims_report import REFERENCES

    # the sample shards hold 2 val objects: best.pt is kept with --val-min-objects 1
    preset = ClaimsPreset(steps=2, batch_size=4, lr=1e-3, tiny=True, extra={"val_min_objects": 1})
    out = tmp_path / "claims"
    lines = []
    results = run_all(sample_shards, sample_shards, out, preset, eval_split="test", device="cpu", echo=lines.append)
    assert set(results) == set(RUNS) | set(REFERENCES)  # + the rows that read no image
    for name in RUNS:
        cfg = yaml.safe_load((out / "runs" / name / "seed-0" / "config.yaml").read_text())
        assert cfg["steps"] == 2 and cfg["seed"] == 0  # equal budgets, one seed
        assert (out / "runs" / name / "seed-0" / "eval" / "metrics.json").is_file()
    modes = {n: yaml.safe_load((out / "runs" / n / "seed-0" / "config.yaml").read_text()) for n in RUNS}
    assert modes["sup-1tube"]["model"]["voxel_decoder"] == "1tube"
    assert modes["semi"]["mode"] == "semi" and modes["labeled-only"]["mode"] == "labeled-only"
    assert modes["ray"]["loss_weights"]["proj"] == 0.0 and modes["ray-proj"]["loss_weights"]["proj"] == 0.125
    # best.pt of every run is what was evaluated; the ablations learn no pose: picked by IoU alone
    assert {n for n in RUNS if modes[n]["select_by"] == "iou"} == {"ray", "ray-proj"}
    assert all(json.loads((out / "runs" / n / "seed-0" / "eval" / "metrics.json").read_text())["checkpoint"]
               .endswith("best.pt") for n in RUNS)
    report = (out / "claims.md").read_text()
    for title in ("Ours (Sup), 3 tubes", "Ours (Sup), 1 tube", "labelled only", "Ours (Semi)",
                  "Ray (true pose)", "Ray + Projection (true pose)", "category mean shape (no image)",
                  "nearest training shape (oracle)",
                  "| claim | measured | difference ± σ | holds (means) | beyond 2σ |"):
        assert title in report, title
    saved = json.loads((out / "claims.json").read_text())
    assert saved["results"]["semi"]["mean"]["voxel_iou_0.4"] == results["semi"]["mean"]["voxel_iou_0.4"]
    assert (out / "claims.png").stat().st_size > 10_000
    assert "n/a (1 seed)" in report and "±" not in report.split("### Claims")[0]  # one seed: no error bars
    # a rerun trains nothing: every run is read back
    again = []
    run_all(sample_shards, sample_shards, out, preset, eval_split="test", device="cpu", echo=again.append)
    assert sum("done before" in line for line in again) == len(RUNS)
    # --pick last on the same study: last.pt is evaluated (into eval-last/), not best.pt's figures
    # read back, and reported beside the best pick's claims.md
    before = report
    run_all(sample_shards, sample_shards, out, preset, eval_split="test", device="cpu", runs=["semi"],
            pick="last", echo=again.append)
    last = json.loads((out / "runs" / "semi" / "seed-0" / "eval-last" / "metrics.json").read_text())
    assert last["checkpoint"].endswith("last.pt")
    assert (out / "claims-last.md").is_file() and (out / "claims.md").read_text() == before
    # reference rows that cannot be made (fault injected: e.g. eval categories with no training
    # objects) cost the report nothing but those rows, and say why
    import sc3d_train.evaluation.claims as claims_module
    from sc3d_train.data.dataset import DataError

    def fail(*args, **kwargs):
        raise DataError("E: no held-out category has training objects")

    monkeypatch.setattr(claims_module, "shape_baselines", fail)
    said = []
    results = run_all(sample_shards, sample_shards, out, preset, eval_split="test", device="cpu", echo=said.append)
    assert set(results) == set(RUNS) and "no reference rows: E: no held-out category" in "\n".join(said)
    assert "nearest training shape" not in (out / "claims.md").read_text()


def test_claims_cli_refuses_unknown_runs(sample_shards, tmp_path):
    r = run_cli(main, ["claims", "--train-shards", sample_shards, "--eval-shards", sample_shards,
                       "--out", tmp_path / "c", "--runs", "sup-3tube,bogus"], expect_exit=2)
    assert "bogus" in r.output


def test_claims_with_two_seeds_reports_mean_and_standard_deviation(sample_shards, tmp_path):
    """``--seeds 2``: each run trained with seeds 0 and 1 (its own folder), every cell the mean ±
    sample standard deviation of the two evaluations, recomputed here from the per-seed
    metrics.json files; the claim carries sigma = sqrt(s_a^2 / 2 + s_b^2 / 2)."""
    import numpy as np

    from sc3d_train.evaluation.claims import ClaimsPreset, run_all

    preset = ClaimsPreset(steps=2, batch_size=4, lr=1e-3, tiny=True, extra={"base_channels": 4})
    out = tmp_path / "claims"

    def study():
        lines = []
        run_all(sample_shards, sample_shards, out, preset, "test", "cpu", runs=["labeled-only", "semi"],
                seeds=2, echo=lines.append)
        return "\n".join(lines)

    study()
    saved = json.loads((out / "claims.json").read_text())
    assert saved["meta"]["seeds"] == [0, 1]
    per_seed = {}
    for name in ("labeled-only", "semi"):
        for seed in (0, 1):
            run = out / "runs" / name / f"seed-{seed}"
            assert yaml.safe_load((run / "config.yaml").read_text())["seed"] == seed
            per_seed[name, seed] = json.loads((run / "eval" / "metrics.json").read_text())
        res = saved["results"][name]
        assert res["seeds"] == [0, 1]
        for cat, figures in res["per_category"].items():
            for key in ("voxel_iou_0.4", "pose_rotation_median", "pose_rotation_acc30"):
                vals = [per_seed[name, s]["per_category"][cat][key] for s in (0, 1)]
                assert figures[key] == pytest.approx(np.mean(vals))
                assert res["std"]["per_category"][cat][key] == pytest.approx(np.std(vals, ddof=1))
        vals = [per_seed[name, s]["mean"]["voxel_iou_0.4"] for s in (0, 1)]
        assert res["mean"]["voxel_iou_0.4"] == pytest.approx(np.mean(vals))
        assert res["std"]["mean"]["voxel_iou_0.4"] == pytest.approx(np.std(vals, ddof=1))
    (claim,) = saved["claims"]
    m = {n: [per_seed[n, s]["mean"]["voxel_iou_0.4"] for s in (0, 1)] for n in ("semi", "labeled-only")}
    sigma = np.sqrt(np.var(m["semi"], ddof=1) / 2 + np.var(m["labeled-only"], ddof=1) / 2)
    assert claim["claim"] == "semi > labelled only"
    assert claim["difference"] == pytest.approx(np.mean(m["semi"]) - np.mean(m["labeled-only"]))
    assert claim["sigma"] == pytest.approx(sigma)
    assert claim["beyond_2sigma"] == bool(claim["difference"] > 2 * sigma)
    report = (out / "claims.md").read_text()
    iou = 100 * saved["results"]["semi"]["mean"]["voxel_iou_0.4"]
    iou_sd = 100 * saved["results"]["semi"]["std"]["mean"]["voxel_iou_0.4"]
    assert f"{iou:.1f} ± {iou_sd:.1f} |" in report and "over 2 seeds" in report
    assert ("| yes |" if claim["beyond_2sigma"] else "| no |") in report.splitlines()[-1]
    # resume per (run, seed): a lost evaluation is redone from the trained run, the rest read back
    (out / "runs" / "semi" / "seed-1" / "eval" / "metrics.json").unlink()
    again = study()
    assert again.count("done before") == 3 and "semi seed 1: semi, " in again and "(trained; evaluating)" in again


def test_claims_keeps_the_timings_of_the_runs_it_reads_back(sample_shards, tmp_path):
    """A rerun with ``--runs`` reports the study's finished runs too, but its claims.json dropped
    their timings (only the runs this call trained had one). A run read back keeps the seconds
    of the earlier report; where that report does not hold them, or holds other figures for
    the run (an evaluation redone since), they are null, not left out (noticed in an earlier
    round)."""
    from sc3d_train.evaluation.claims import ClaimsPreset, run_all

    preset = ClaimsPreset(steps=2, batch_size=4, lr=1e-3, tiny=True, extra={"base_channels": 4})
    out = tmp_path / "claims"

    def timings(runs):
        run_all(sample_shards, sample_shards, out, preset, "test", "cpu", runs=runs, echo=lambda line: None)
        return json.loads((out / "claims.json").read_text())["meta"]["timings"]

    first = timings(["ray"])
    second = timings(["ray-proj"])
    assert second["ray/seed-0"] == first["ray/seed-0"] > 0 and second["ray-proj/seed-0"] > 0, second
    saved = json.loads((out / "claims.json").read_text())
    del saved["meta"]["timings"]["ray/seed-0"]
    saved["results"]["ray-proj"]["per_seed"]["0"]["mean"]["voxel_iou_0.4"] = -1.0
    (out / "claims.json").write_text(json.dumps(saved))
    assert timings(["ray"]) == {"ray/seed-0": None, "ray-proj/seed-0": None}


def test_cpu_preset_pretrains_semi_for_200_steps_and_leaves_the_other_runs_alone(sample_shards, tmp_path):
    """The cpu preset's semi run pretrains on its labelled objects for 200 of its 700 steps (the
    setting adopted by the rule in docs/training.md); the other runs keep fit's settings (their
    studies stay resumable): labelled-only has no pretraining phase (None)."""
    from sc3d_train.evaluation.claims import PRESETS, run_config

    semi = run_config("semi", PRESETS["cpu"], sample_shards, tmp_path / "semi")
    only = run_config("labeled-only", PRESETS["cpu"], sample_shards, tmp_path / "only")
    assert (semi.mode, semi.steps, semi.pretrain_steps) == ("semi", 700, 200)
    assert (only.mode, only.steps, only.pretrain_steps) == ("labeled-only", 700, None)
