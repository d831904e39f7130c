"""The report of ``sc3d-train claims``: each run's evaluations aggregated over seeds
(:func:`aggregate`: mean and sample standard deviation of every figure), the paper's tables
(``claims.md``, :func:`format_report`), the claims checked with their error bars
(:func:`check_claims`), ``claims.json`` and the figure ``claims.png``. The training and
evaluation of the runs is :mod:`sc3d_train.evaluation.claims`."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from sc3d_data.io.pictures import write_figure

RUNS = ("sup-3tube", "sup-1tube", "labeled-only", "semi", "ray", "ray-proj")
#: reference rows that read no image (:mod:`sc3d_train.evaluation.shape_baselines`): no seeds, no pose
REFERENCES = ("mean-shape", "nearest-shape")
#: rows without a pose estimate
NO_POSE = ("ray", "ray-proj", *REFERENCES)


def _stats(values: list) -> dict:
    """``{"mean", "std", "values"}`` of per-seed values (None: a figure a seed could not give,
    left out); ``std`` is the sample standard deviation (ddof 1), None for fewer than 2 values."""
    vals = [float(v) for v in values if v is not None]
    if not vals:
        return {"mean": None, "std": None, "values": values}
    return {"mean": float(np.mean(vals)), "std": float(np.std(vals, ddof=1)) if len(vals) > 1 else None,
            "values": values}


def aggregate(by_seed: dict) -> dict:
    """One run's eval metrics over seeds (``{seed: metrics}``) in the shape of one evaluation
    (``per_category``, ``mean``, ``overall``: the mean over seeds of each figure), plus ``std``
    (the same blocks holding the sample standard deviation, None for one seed), ``seeds`` and
    ``per_seed`` (each seed's blocks)."""
    seeds = sorted(by_seed)
    runs = [by_seed[s] for s in seeds]
    out = {"seeds": seeds, "per_seed": {s: {k: by_seed[s][k] for k in ("per_category", "mean", "overall")}
                                        for s in seeds}}

    def block(get) -> tuple[dict, dict]:
        keys = sorted({k for r in runs for k in (get(r) or {})})
        stats = {k: _stats([(get(r) or {}).get(k) for r in runs]) for k in keys}
        return {k: v["mean"] for k, v in stats.items()}, {k: v["std"] for k, v in stats.items()}

    out["std"] = {"per_category": {}}
    out["per_category"] = {}
    for c in sorted({c for r in runs for c in r["per_category"]}):
        out["per_category"][c], out["std"]["per_category"][c] = block(lambda r, c=c: r["per_category"].get(c))
    for name in ("mean", "overall"):
        out[name], out["std"][name] = block(lambda r, name=name: r[name])
    return out


def _categories(results: dict) -> list[str]:
    cats = set()
    for r in results.values():
        cats |= set(r["per_category"])
    return sorted(cats)


def _cell(value, std, fmt: str, scale: float = 1.0) -> str:
    """``mean`` or ``mean ± std`` (``-`` where the figure is missing)."""
    if value is None:
        return "-"
    text = fmt.format(scale * value)
    return text if std is None else f"{text} ± {fmt.format(scale * std)}"


def _row(res: dict, cats: list[str], key: str, fmt: str, scale: float = 1.0) -> list[str]:
    std = res.get("std", {})
    cells = [_cell(res["per_category"].get(c, {}).get(key), std.get("per_category", {}).get(c, {}).get(key), fmt,
                   scale) for c in cats]
    return cells + [_cell(res["mean"].get(key), std.get("mean", {}).get(key), fmt, scale)]


def _header(category: str) -> str:
    """A category's column header: its name (``airplane`` for ``02691156``; a user's category whole,
    as claims.png names it: cut at `` (``, ``chair (metal)`` and ``chair (wood)`` were two columns
    headed ``chair``), a ``|`` escaped (it split the cell: the table had a column too many), and control
    characters as ``io.names.printable`` writes them (a newline cut the header row in two)."""
    from sc3d_data.formats.shapenet import category_name
    from sc3d_data.io.names import printable

    return printable(category_name(category)).replace("|", "\\|")


TITLES = {"sup-3tube": "Ours (Sup), 3 tubes", "sup-1tube": "Ours (Sup), 1 tube", "labeled-only": "labelled only",
          "semi": "Ours (Semi)", "ray": "Ray (true pose)", "ray-proj": "Ray + Projection (true pose)",
          "mean-shape": "*reference:* category mean shape (no image)",
          "nearest-shape": "*reference:* nearest training shape (oracle)"}


def format_report(results: dict) -> str:
    """The markdown tables: reconstruction (IoU@0.4 %, per category and mean), pose (median
    rotation error, share within 30 deg), the claims. With several seeds every cell is
    ``mean ± sample standard deviation`` over the seeds."""
    from sc3d_data.formats.shapenet import category_label
    from sc3d_data.io.names import printable

    cats = _categories(results)
    names = [_header(c) for c in cats]
    head = "| run | " + " | ".join(names) + " | Mean |\n|---|" + "---|" * (len(cats) + 1) + "\n"
    seeds = sorted({len(r["seeds"]) for r in results.values() if "seeds" in r})
    over = f" (mean ± standard deviation over {seeds[0]} seeds)" if seeds and seeds[-1] > 1 else ""
    out = [f"### Reconstruction: voxel IoU@0.4 (%) on held-out objects{over}\n\n", head]
    for name in RUNS + REFERENCES:
        if name in results:
            out.append(f"| {TITLES[name]} | " + " | ".join(_row(results[name], cats, "voxel_iou_0.4", "{:.1f}", 100))
                       + " |\n")
    if any(name in results for name in REFERENCES):
        out.append("\nReference rows read no image: the training objects' occupancy frequency per category "
                   "(thresholded at 0.4), and for each held-out object the training object of its category "
                   "closest to its ground truth (a bound for any method that retrieves a training shape; it "
                   "reads the answer). A model near the first row has learnt its categories' average shape.\n")
        left_out = next((results[n].get("left_out") for n in REFERENCES if results.get(n, {}).get("left_out")), None)
        if left_out:
            out.append(f"\nThe reference rows have no figure for {', '.join(printable(category_label(c)) for c in left_out)}: "
                       "no training object of that category to take a shape from; and so no Mean, as the runs' "
                       f"Mean is over all {len(cats)} categories.\n")
    out.append("\n### Pose (no pose labels in training): median rotation error (deg) / share within 30 deg"
               f"{over}\n\n")
    out.append(head)
    for name in (n for n in RUNS if n not in NO_POSE):
        if name in results:
            med = _row(results[name], cats, "pose_rotation_median", "{:.1f}")
            acc = _row(results[name], cats, "pose_rotation_acc30", "{:.2f}")
            out.append(f"| {TITLES[name]} | " + " | ".join(f"{m} / {a}" for m, a in zip(med, acc)) + " |\n")
    out.append("\n### Claims\n\nmean IoU@0.4 (mean of categories); σ: the standard deviation of the difference "
               "of the two means, sqrt(s_a² / K + s_b² / K) with s the sample standard deviation over K seeds\n\n"
               "| claim | measured | difference ± σ | holds (means) | beyond 2σ |\n|---|---|---|---|---|\n")
    for c in check_claims(results):
        sigma = "" if c["sigma"] is None else f" ± {c['sigma']:.3f}"
        beyond = "n/a (1 seed)" if c["beyond_2sigma"] is None else ("yes" if c["beyond_2sigma"] else "no")
        out.append(f"| {c['claim']} | {c['measured']} | {c['difference']:+.3f}{sigma} | "
                   f"{'yes' if c['holds'] else 'no'} | {beyond} |\n")
    return "".join(out)


CLAIMS = (("sup-3tube", "sup-1tube", "3 tubes >= 1 tube", False),
          ("semi", "labeled-only", "semi > labelled only", True),
          ("ray-proj", "ray", "ray + projection >= ray", False))


def check_claims(results: dict) -> list[dict]:
    """The paper's qualitative claims on the mean IoU@0.4 over categories: per claim ``claim``,
    ``measured`` (text), ``difference`` (a - b of the means over seeds), ``sigma`` (standard
    deviation of that difference: ``sqrt(s_a^2 / K_a + s_b^2 / K_b)``; None with one seed),
    ``holds`` (on the means; ``>`` for the strict claim, else ``>=``) and ``beyond_2sigma``
    (``difference > 2 sigma``; None with one seed)."""
    rows = []
    for a, b, text, strict in CLAIMS:
        if a not in results or b not in results:
            continue
        (ma, sa, ka), (mb, sb, kb) = ((results[n]["mean"]["voxel_iou_0.4"],
                                       results[n].get("std", {}).get("mean", {}).get("voxel_iou_0.4"),
                                       len(results[n].get("seeds", [0]))) for n in (a, b))
        d = ma - mb
        sigma = None if sa is None or sb is None else float(np.sqrt(sa ** 2 / ka + sb ** 2 / kb))
        rows.append({"claim": text, "a": a, "b": b,
                     "measured": f"{_cell(ma, sa, '{:.3f}')} vs {_cell(mb, sb, '{:.3f}')}",
                     "difference": d, "sigma": sigma, "holds": d > 0 if strict else d >= 0,
                     "beyond_2sigma": None if sigma is None else bool(d > 2 * sigma)})
    return rows


def plot_report(results: dict, path: Path) -> None:
    """IoU@0.4 per category (bars per run) and the rotation-error share within 30 deg (error bars:
    the standard deviation over seeds). Categories are named as ``io.drawn_names.mpl_name`` writes
    them (a synset id by its name; a user's category whole, not cut at its first `` (``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sc3d_data.formats.shapenet import category_name
    from sc3d_data.io.drawn_names import mpl_name

    cats = _categories(results)
    slanted = len(cats) + 1 > 6
    # a name no wider than its bar group (5.8 inches of panel), or than 1.25 inches slanted; what
    # the font cannot draw (CJK) as \uXXXX: it was drawn as empty boxes, with warnings on stderr
    room = 90 if slanted else 0.9 * 5.8 * 72 / (len(cats) + 1)
    labels = [mpl_name(category_name(c), room, 8) for c in cats] + ["mean"]
    fig, axes = plt.subplots(1, 2, figsize=(13, 4))
    names = list(results)
    width = 0.8 / max(len(names), 1)
    x = np.arange(len(labels))
    for k, name in enumerate(names):
        res = results[name]
        for ax, key in zip(axes, ("voxel_iou_0.4", "pose_rotation_acc30")):
            vals = [res["per_category"].get(c, {}).get(key) for c in cats] + [res["mean"].get(key)]
            vals = [np.nan if v is None else v for v in vals]
            std = res.get("std", {})
            err = [std.get("per_category", {}).get(c, {}).get(key) for c in cats] + [std.get("mean", {}).get(key)]
            if key.startswith("pose") and name in NO_POSE:
                continue
            ax.bar(x + k * width, vals, width, label=name, yerr=[0 if e is None else e for e in err], capsize=2)
    for ax, title in zip(axes, ("voxel IoU@0.4 (held-out objects)", "share of views with rotation error <= 30 deg")):
        ax.set_xticks(x + 0.4 - width / 2)
        # 3D-R2N2's 13 categories side by side ran into each other ("lamploudspeakerrifle"): slanted
        slant = {"rotation": 35, "ha": "right", "rotation_mode": "anchor"} if slanted else {}
        ax.set_xticklabels(labels, fontsize=8, parse_math=False, **slant)
        ax.set_title(title)
        ax.set_ylim(0, 1)
    # above the panels, not over the bars (in the IoU panel it hid the last categories' bars)
    fig.legend(*axes[0].get_legend_handles_labels(), loc="upper center", ncol=len(names), fontsize=7, frameon=False)
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    write_figure(fig, path, dpi=90)
    plt.close(fig)


def kept_timings(timings: dict, earlier: Path, per_seed: dict) -> dict:
    """``timings`` (``"RUN/seed-S"``: seconds this call spent training and evaluating it, None
    where it read the evaluation back) with each None replaced by the seconds that the report
    ``earlier`` (this study's ``STEM.json``, written by the call that did it or kept from one)
    records for it, where that report holds the same figures for it (``per_seed``: run -> seed
    -> metrics); else left None, written as null: not known (a call stopped before its report,
    an evaluation redone since, a report of a version that dropped them)."""
    try:
        old = json.loads(Path(earlier).read_text())
        old_times, old_results = old["meta"]["timings"], old["results"]
    except (OSError, ValueError, KeyError, TypeError):
        return dict(timings)

    def same(name: str, seed: int) -> bool:
        figures = {k: per_seed[name][seed][k] for k in ("per_category", "mean", "overall")}
        try:
            theirs = old_results[name]["per_seed"][str(seed)]
        except (KeyError, TypeError):
            return False
        return json.dumps(theirs, sort_keys=True, default=str) == json.dumps(figures, sort_keys=True, default=str)

    out = dict(timings)
    for key, seconds in timings.items():
        name, seed = key.rsplit("/seed-", 1)
        if seconds is None and isinstance(old_times, dict) and same(name, int(seed)):
            out[key] = old_times.get(key)
    return out


def write_report(results: dict, out: Path, stem: str = "claims", **meta) -> str:
    """``STEM.md`` (:func:`format_report`), ``STEM.json`` (``meta``; per run the means, ``std``,
    ``seeds`` and ``per_seed`` blocks; ``claims``: :func:`check_claims`) and ``STEM.png``, each
    written whole or not at all; a link at one of those names is replaced, not written through."""
    from sc3d_data.io.shards import atomic_write_bytes

    text = format_report(results)
    # written whole or not at all, replacing a link at the name, never writing through it
    atomic_write_bytes(Path(out) / f"{stem}.md", text.encode())
    keys = ("per_category", "mean", "overall", "std", "seeds", "per_seed", "left_out")
    slim = {k: {key: v[key] for key in keys if key in v} for k, v in results.items()}
    atomic_write_bytes(Path(out) / f"{stem}.json", json.dumps(
        {"meta": meta, "results": slim, "claims": check_claims(results)}, indent=1, default=str).encode())
    plot_report(results, Path(out) / f"{stem}.png")
    return text
