"""``sc3d-train claims``: train the paper's comparisons with one seed and equal budgets, evaluate
each on held-out shards, and write the paper's tables (markdown) and one figure.

Runs (each a normal ``fit`` run folder under ``OUT/runs/NAME`` and its evaluation under
``OUT/runs/NAME/eval``; a rerun skips runs whose evaluation exists, so the command resumes):

=================  ============================================================================
``sup-3tube``       supervised, all training objects, 3-tube voxel decoder (the paper's model)
``sup-1tube``       the same with the 1-tube decoder (ablation, paper Table "voxel decoder")
``labeled-only``    the labelled fraction alone (supervised loss)
``semi``            the same labelled fraction + the unlabelled rest (``fit --semi``)
``ray``             voxels learnt from masks alone at the TRUE pose, L_ray only (ablation,
                    paper Table "2D-3D self-consistency"; DRC's setting)
``ray-proj``        the same with L_ray + L_proj
=================  ============================================================================

Presets (:data:`PRESETS`): ``cpu`` (the tiny network, 700 steps of 32: about 30-40 min for ~200
training objects on 2 CPU cores) and ``paper`` (the paper's width and Adam 2e-4, batch 48, for
a GPU). Every run gets the same step budget and seed.

Outputs: ``OUT/claims.md`` (IoU@0.4 per category and mean, in the paper's layout; pose errors per
category; the two ablations), ``OUT/claims.json`` (every number) and ``OUT/claims.png``.
"""
from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

from sc3d_train.command_config import ClaimsConfig
from sc3d_train.config import RunConfig
from sc3d_train.config_io import defaults_of

RUNS = ("sup-3tube", "sup-1tube", "labeled-only", "semi", "ray", "ray-proj")


#: ``fit``'s defaults (:class:`RunConfig`), which a preset does not set again
_FIT = defaults_of(RunConfig)


@dataclass(frozen=True)
class ClaimsPreset:
    """Budget and network of every run of a claims study (unset fields: ``fit``'s defaults)."""

    steps: int
    batch_size: int
    lr: float
    tiny: bool
    lr_schedule: str = _FIT["lr_schedule"]
    labeled_fraction: float = _FIT["labeled_fraction"]
    seed: int = _FIT["seed"]
    runs: tuple = RUNS
    extra: dict = field(default_factory=dict)


PRESETS = {
    "cpu": ClaimsPreset(steps=700, batch_size=32, lr=_FIT["lr"], tiny=True),
    "paper": ClaimsPreset(steps=20000, batch_size=48, lr=2e-4, tiny=False, lr_schedule="constant"),
}


def run_config(name: str, preset: ClaimsPreset, shards: Path, out: Path, device: str = ClaimsConfig.device,
               workers: int = ClaimsConfig.workers) -> RunConfig:
    """The :class:`RunConfig` of run ``name`` (one of :data:`RUNS`)."""
    from sc3d_train.resolve import resolve_config

    options = dict(shards=str(Path(shards).resolve()), out=str(out), steps=preset.steps,
                   batch_size=preset.batch_size, lr=preset.lr, lr_schedule=preset.lr_schedule, seed=preset.seed,
                   labeled_fraction=preset.labeled_fraction, device=device, workers=workers,
                   progress=False, checkpoint_every=preset.steps)
    options["mode"] = {"labeled-only": "labeled-only", "semi": "semi", "ray": "true-pose-masks",
                       "ray-proj": "true-pose-masks"}.get(name, "supervised")
    model_options = {"tiny": preset.tiny, "voxel_decoder": "1tube" if name == "sup-1tube" else "3tube"}
    cfg = resolve_config(options, model_options)
    if name == "ray":
        cfg = replace(cfg, loss_weights=replace(cfg.loss_weights, proj=0.0))
    return cfg


def run_all(train_shards: Path, eval_shards: Path, out: Path,
            preset: "str | ClaimsPreset" = ClaimsConfig.preset, eval_split: str = ClaimsConfig.eval_split,
            device: str = ClaimsConfig.device, workers: int = ClaimsConfig.workers, runs=None,
            echo=print) -> dict:
    """Train and evaluate every run of ``preset`` (skipping finished ones); write the report.
    Returns ``{run name: eval metrics}``."""
    from sc3d_train.evaluate import evaluate
    from sc3d_train.trainer import fit

    p = PRESETS[preset] if isinstance(preset, str) else preset
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    results, timings = {}, {}
    names = list(runs or p.runs)
    for i, name in enumerate(names):
        run_dir = out / "runs" / name
        metrics_file = run_dir / "eval" / "metrics.json"
        if metrics_file.is_file():
            echo(f"[{i + 1}/{len(names)}] {name}: done before, reading {metrics_file}")
            results[name] = json.loads(metrics_file.read_text())
            continue
        t0 = time.perf_counter()
        resume = (run_dir / "checkpoints" / "last.pt").is_file()
        cfg = RunConfig.load(RunConfig.path_in(run_dir)) if resume else \
            run_config(name, p, train_shards, run_dir, device, workers)
        echo(f"[{i + 1}/{len(names)}] {name}: {cfg.mode}, {cfg.steps} steps of {cfg.batch_size}"
             + (" (resuming)" if resume else ""))
        fit(cfg, resume=resume)
        res = evaluate(run_dir / "checkpoints" / "last.pt", eval_shards, eval_split, run_dir / "eval", device)
        results[name] = res
        timings[name] = time.perf_counter() - t0
        echo(f"    {name}: mean IoU@0.4 {res['mean']['voxel_iou_0.4']:.3f}, median rotation error "
             f"{res['mean']['pose_rotation_median']:.1f} deg ({timings[name] / 60:.1f} min)")
    report = write_report(results, out, preset=asdict(p), eval_split=eval_split,
                          train_shards=str(train_shards), eval_shards=str(eval_shards), timings=timings)
    echo(f"wrote {out / 'claims.md'}, {out / 'claims.json'}, {out / 'claims.png'}")
    echo(report)
    return results


def _categories(results: dict) -> list[str]:
    cats = set()
    for r in results.values():
        cats |= set(r["per_category"])
    return sorted(cats)


def _row(res: dict, cats: list[str], key: str, fmt: str) -> list[str]:
    cells = []
    for c in cats:
        v = res["per_category"].get(c, {}).get(key)
        cells.append("-" if v is None else fmt.format(v))
    v = res["mean"].get(key)
    return cells + ["-" if v is None else fmt.format(v)]


def format_report(results: dict) -> str:
    """The markdown tables: reconstruction (IoU@0.4 %, per category and mean), pose (median
    rotation error, share within 30 deg), ablations."""
    from sc3d_data.formats.shapenet import category_label

    cats = _categories(results)
    names = [category_label(c).split(" (")[0] for c in cats]
    head = "| run | " + " | ".join(names) + " | Mean |\n|---|" + "---|" * (len(cats) + 1) + "\n"
    titles = {"sup-3tube": "Ours (Sup), 3 tubes", "sup-1tube": "Ours (Sup), 1 tube",
              "labeled-only": "labelled only", "semi": "Ours (Semi)",
              "ray": "Ray (true pose)", "ray-proj": "Ray + Projection (true pose)"}
    out = ["### Reconstruction: voxel IoU@0.4 (%) on held-out objects\n", head]
    for name in ("sup-3tube", "sup-1tube", "labeled-only", "semi", "ray", "ray-proj"):
        if name in results:
            cells = _row(results[name], cats, "voxel_iou_0.4", "{:.3f}")
            cells = [c if c == "-" else f"{100 * float(c):.1f}" for c in cells]
            out.append(f"| {titles[name]} | " + " | ".join(cells) + " |\n")
    out.append("\n### Pose (no pose labels in training): median rotation error (deg) / share within 30 deg\n\n")
    out.append(head)
    for name in ("sup-3tube", "sup-1tube", "labeled-only", "semi"):
        if name in results:
            med = _row(results[name], cats, "pose_rotation_median", "{:.1f}")
            acc = _row(results[name], cats, "pose_rotation_acc30", "{:.2f}")
            out.append(f"| {titles[name]} | " + " | ".join(f"{m} / {a}" for m, a in zip(med, acc)) + " |\n")
    out.append("\n### Claims\n\n| claim | measured | holds |\n|---|---|---|\n")
    for claim, measured, holds in check_claims(results):
        out.append(f"| {claim} | {measured} | {'yes' if holds else 'no'} |\n")
    return "".join(out)


def check_claims(results: dict) -> list[tuple[str, str, bool]]:
    """The paper's qualitative claims, checked on the measured means."""
    def mean_iou(n):
        return results[n]["mean"]["voxel_iou_0.4"]

    rows = []
    for a, b, text in (("sup-3tube", "sup-1tube", "3 tubes >= 1 tube"),
                       ("semi", "labeled-only", "semi > labelled only"),
                       ("ray-proj", "ray", "ray + projection >= ray")):
        if a in results and b in results:
            holds = mean_iou(a) > mean_iou(b) if a == "semi" else mean_iou(a) >= mean_iou(b)
            rows.append((text, f"{mean_iou(a):.3f} vs {mean_iou(b):.3f}", holds))
    return rows


def plot_report(results: dict, path: Path) -> None:
    """IoU@0.4 per category (bars per run) and the rotation-error share within 30 deg."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from sc3d_data.formats.shapenet import category_label

    cats = _categories(results)
    labels = [category_label(c).split(" (")[0] for c in cats] + ["mean"]
    fig, axes = plt.subplots(1, 2, figsize=(13, 4))
    names = list(results)
    width = 0.8 / max(len(names), 1)
    x = np.arange(len(labels))
    for k, name in enumerate(names):
        res = results[name]
        for ax, key in zip(axes, ("voxel_iou_0.4", "pose_rotation_acc30")):
            vals = [res["per_category"].get(c, {}).get(key) for c in cats] + [res["mean"].get(key)]
            vals = [np.nan if v is None else v for v in vals]
            if key.startswith("pose") and name in ("ray", "ray-proj"):
                continue
            ax.bar(x + k * width, vals, width, label=name)
    for ax, title in zip(axes, ("voxel IoU@0.4 (held-out objects)", "share of views with rotation error <= 30 deg")):
        ax.set_xticks(x + 0.4 - width / 2)
        ax.set_xticklabels(labels, fontsize=8)
        ax.set_title(title)
        ax.set_ylim(0, 1)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def write_report(results: dict, out: Path, **meta) -> str:
    text = format_report(results)
    (Path(out) / "claims.md").write_text(text)
    slim = {k: {"per_category": v["per_category"], "mean": v["mean"], "overall": v["overall"]}
            for k, v in results.items()}
    (Path(out) / "claims.json").write_text(json.dumps({"meta": meta, "results": slim}, indent=1, default=str))
    plot_report(results, Path(out) / "claims.png")
    return text
