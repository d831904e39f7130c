"""``sc3d-train claims``: train the paper's comparisons with K seeds and equal budgets, evaluate
each on held-out shards, and write the paper's tables (markdown) and one figure.

Runs (each a normal ``fit`` run folder under ``OUT/runs/NAME/seed-S`` per seed and its evaluation
of ``best.pt`` (``--pick last``: ``last.pt``) under ``.../eval``; a rerun skips (run, seed) pairs
whose evaluation of the same split and shards, unchanged since (``data_sha256``), exists and resumes a half-trained one, so the
command resumes; a run folder of other settings is refused):

=================  ============================================================================
``sup-3tube``       supervised, all training objects, 3-tube voxel decoder (the paper's model)
``sup-1tube``       the same with the 1-tube decoder (ablation, paper Table "voxel decoder")
``labeled-only``    the labelled fraction alone (supervised loss)
``semi``            the same labelled fraction + the unlabelled rest (``fit --semi``)
``ray``             voxels learnt from masks alone at the TRUE pose, L_ray only (ablation,
                    paper Table "2D-3D self-consistency"; DRC's setting)
``ray-proj``        the same with L_ray + L_proj
=================  ============================================================================

Presets (:data:`PRESETS`): ``cpu`` (the tiny network, 700 steps of 32, the semi run's labelled
pretraining 200 steps: about 40 min a seed for ~200 training objects on 2 CPU cores) and ``paper`` (the paper's width and Adam 2e-4, batch 48, for
a GPU). Every run gets the same step budget and seeds: ``--seeds K`` trains each with seeds
``seed .. seed + K - 1``; every cell of the tables is then the mean ± sample standard deviation
over the K evaluations, and each claim says whether it holds on the means and whether the
difference exceeds two standard deviations of the difference of the means
(:func:`~sc3d_train.evaluation.claims_report.check_claims`).

Outputs: ``OUT/claims.md`` (IoU@0.4 per category and mean, in the paper's layout; pose errors per
category; the two ablations; two reference rows that read no image:
:mod:`~sc3d_train.evaluation.shape_baselines`), ``OUT/claims.json`` (every number) and ``OUT/claims.png``.
"""
from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path

from sc3d_train.evaluation.claims_data import check_evaluable, check_held_out, check_not_selection
from sc3d_train.evaluation.claims_report import RUNS, aggregate, kept_timings, write_report
from sc3d_train.evaluation.evaluated_data import split_digest
from sc3d_train.evaluation.shape_baselines import shape_baselines
from sc3d_train.data.completeness import require_complete
from sc3d_train.data.dataset import DataError, ShardDataset
from sc3d_train.settings.command_config import ClaimsConfig
from sc3d_train.settings.config import ModelConfig, RunConfig
from sc3d_train.settings.config_io import defaults_of

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
    #: further ``fit`` settings: RunConfig fields (``val_every``, ...) and ModelConfig fields
    #: (``base_channels``, ...)
    extra: dict = field(default_factory=dict)
    #: further ``fit`` settings of the ``semi`` run only, after ``extra``
    semi_extra: dict = field(default_factory=dict)


PRESETS = {
    # semi: 200 labelled steps of 700 before the mixed phase (fit's default: half the steps);
    # chosen on split 0 and confirmed by a rule written before the run on an independent split
    # (docs/training.md, "Measured: the paper's comparisons")
    "cpu": ClaimsPreset(steps=700, batch_size=32, lr=_FIT["lr"], tiny=True, semi_extra={"pretrain_steps": 200}),
    "paper": ClaimsPreset(steps=20000, batch_size=48, lr=2e-4, tiny=False, lr_schedule="constant"),
}


#: checkpoints a claims run writes (every steps / N steps), so that a rerun resumes a run cut short
#: near where it stopped; dropped when the run is finished (:func:`drop_intermediate_checkpoints`)
CHECKPOINTS_PER_RUN = 10


def run_config(name: str, preset: ClaimsPreset, shards: Path, out: Path, device: str = ClaimsConfig.device,
               workers: int | None = ClaimsConfig.workers, seed: int | None = None, resume: bool = False) -> RunConfig:
    """The :class:`RunConfig` of run ``name`` (one of :data:`RUNS`) with ``seed`` (None: the
    preset's). The ablations at the true pose train no pose, so their ``best.pt`` is picked by IoU.
    ``resume``: the config saved in ``out``, refused (``CheckpointError``) when that run was trained
    with other settings or on shards that changed since (``resolve_config(resume=True)``)."""
    from sc3d_train.loop.resolve import resolve_config

    options = dict(shards=str(Path(shards).resolve()), out=str(out), steps=preset.steps,
                   batch_size=preset.batch_size, lr=preset.lr, lr_schedule=preset.lr_schedule,
                   seed=preset.seed if seed is None else seed,
                   labeled_fraction=preset.labeled_fraction, device=device, workers=workers,
                   progress=False, checkpoint_every=-(-preset.steps // CHECKPOINTS_PER_RUN))
    options["mode"] = {"labeled-only": "labeled-only", "semi": "semi", "ray": "true-pose-masks",
                       "ray-proj": "true-pose-masks"}.get(name, "supervised")
    if options["mode"] == "true-pose-masks":
        options["select_by"] = "iou"
    model_options = {"tiny": preset.tiny, "voxel_decoder": "1tube" if name == "sup-1tube" else "3tube"}
    model_fields = {f.name for f in fields(ModelConfig)}
    for k, v in {**preset.extra, **(preset.semi_extra if name == "semi" else {})}.items():
        (model_options if k in model_fields else options)[k] = v
    cfg = resolve_config(options, model_options, resume=resume)
    if name == "ray" and not resume:
        cfg = replace(cfg, loss_weights=replace(cfg.loss_weights, proj=0.0))
    return cfg


def drop_intermediate_checkpoints(run_dir: Path, steps: int) -> None:
    """Remove the ``step_XXXXXX.pt`` of ``run_dir`` before step ``steps`` once its run is finished:
    they serve only to resume a run cut short (``last.pt`` and ``best.pt`` stay, what ``eval`` reads)."""
    from sc3d_train.loop.checkpoint import checkpoint_dir

    for p in checkpoint_dir(run_dir).glob("step_*.pt"):
        if p.name[5:-3].isdigit() and int(p.name[5:-3]) < steps:
            p.unlink(missing_ok=True)


#: the most seeds of a study: each seed trains and evaluates every run again (the cpu preset: about
#: 40 min a seed), so 100 is already days of computing; more is a mistyped number
MAX_SEEDS = 100


def seed_list(preset: ClaimsPreset, seeds: int) -> list[int]:
    """The seeds of a study: ``preset.seed``, ``preset.seed + 1``, ... (``seeds`` of them, 1 to
    :data:`MAX_SEEDS`; else ``ValueError`` naming ``--seeds``)."""
    if not 1 <= seeds <= MAX_SEEDS:
        raise ValueError(f"seeds (--seeds) must be in [1, {MAX_SEEDS}], got {seeds} (each seed trains and evaluates "
                         f"every run again: {MAX_SEEDS} is already days of computing)")
    return [preset.seed + k for k in range(seeds)]


def check_study_options(preset: ClaimsPreset, seeds: int, device: str) -> list[int]:
    """The study's seeds (:func:`seed_list`), once ``seeds`` and ``device`` are known to serve
    (``ValueError`` naming the option otherwise), before anything is trained or written."""
    from sc3d_train.loop.runtime import resolve_device

    seed_values = seed_list(preset, seeds)
    resolve_device(device)
    return seed_values


def run_folder(out: Path, name: str, seed: int) -> Path:
    """``OUT/runs/NAME/seed-S``: the ``fit`` run of ``name`` with ``seed`` (its evaluation in :func:`eval_folder`)."""
    return Path(out) / "runs" / name / f"seed-{seed}"


def eval_folder(run_dir: Path, pick: str) -> Path:
    """Where the evaluation of ``run_dir``'s ``pick`` checkpoint goes: ``eval/`` for ``best`` (the
    default), ``eval-last/`` for ``last``, so that a study read back with the other pick evaluates
    that checkpoint instead of reusing the first pick's figures."""
    return Path(run_dir) / ("eval" if pick == "best" else f"eval-{pick}")


def report_stem(pick: str) -> str:
    """``claims`` (``claims.md``, ``.json``, ``.png``) for ``best``; ``claims-last`` for ``last``."""
    return "claims" if pick == "best" else f"claims-{pick}"


def train_and_evaluate(name: str, seed: int, p: ClaimsPreset, train_shards: Path, eval_shards: Path, out: Path,
                       eval_split: str, device: str, workers: int | None, pick: str, echo,
                       data_digest: str | None = None) -> tuple[dict, float | None]:
    """The eval metrics of run ``name`` with ``seed``: read back when its evaluation of the eval
    shards as they are now exists (``data_digest``: their
    :func:`~sc3d_train.evaluation.evaluated_data.split_digest`, computed here when None), else trained (resumed from its ``last.pt`` when there is one) and evaluated on ``pick``.
    Returns ``(metrics, seconds spent or None when read back)``."""
    from sc3d_train.loop.checkpoint import run_checkpoint
    from sc3d_train.evaluation.evaluate import evaluate
    from sc3d_data.io.outlock import exclusive_lock
    from sc3d_train.loop.trainer import fit
    run_dir = run_folder(out, name, seed)
    metrics_file = eval_folder(run_dir, pick) / "metrics.json"
    saved = RunConfig.path_in(run_dir).is_file()
    trained_steps = RunConfig.load(RunConfig.path_in(run_dir)).steps if saved else None
    cfg = study_run_config(name, seed, p, train_shards, out, device, workers)
    if metrics_file.is_file() and trained_steps in (None, cfg.steps) and \
            evaluated_on(metrics_file, eval_shards, eval_split, data_digest):
        echo(f"{name} seed {seed}: done before, reading {metrics_file}")
        return json.loads(metrics_file.read_text()), None
    t0 = time.perf_counter()
    resume = (run_dir / "checkpoints" / "last.pt").is_file()
    echo(f"{name} seed {seed}: {cfg.mode}, {cfg.steps} steps of {cfg.batch_size}" + (resumed_state(run_dir, cfg.steps)
                                                                                   if resume else ""))
    with exclusive_lock(run_dir, "sc3d-train claims", create=True):  # as `fit` holds its run folder's: one trains it
        fit(cfg, resume=resume, resume_hint="run the same claims command again to resume")
        drop_intermediate_checkpoints(run_dir, cfg.steps)
    res = evaluate(run_checkpoint(run_dir, pick), eval_shards, eval_split, eval_folder(run_dir, pick), device)
    seconds = time.perf_counter() - t0
    echo(f"    {name} seed {seed} (step {res['step']}): mean IoU@0.4 {res['mean']['voxel_iou_0.4']:.3f}, median "
         f"rotation error {res['mean']['pose_rotation_median']:.1f} deg ({seconds / 60:.1f} min)")
    return res, seconds


def study_run_config(name: str, seed: int, p: ClaimsPreset, train_shards: Path, out: Path, device: str,
                     workers: int | None) -> RunConfig:
    """:func:`run_config` of run ``name`` with ``seed`` in study ``out``: its folder's config where it
    holds one, refused (``CheckpointError`` naming the folder) where trained with other settings or data."""
    from sc3d_train.loop.checkpoint import CheckpointError

    run_dir = run_folder(out, name, seed)
    try:
        return run_config(name, p, train_shards, run_dir, device, workers, seed, resume=RunConfig.path_in(run_dir).is_file())
    except CheckpointError as e:
        raise CheckpointError(f"{e} [claims: {out} holds this study's runs; give another --out for other "
                              f"settings or shards]") from e


def check_study_runs(names: list, seeds: list, p: ClaimsPreset, train_shards: Path, out: Path, device: str,
                     workers: int | None) -> None:
    """Refuse (:func:`study_run_config`) before any training where a run of ``names`` x ``seeds`` that
    ``out`` holds was trained with other settings: checked run by run, a rerun with another ``--preset``
    trained its new runs first (hours at the paper preset) and left runs of two settings in ``out``."""
    for name, seed in ((n, s) for n in names for s in seeds):
        if RunConfig.path_in(run_folder(out, name, seed)).is_file():
            study_run_config(name, seed, p, train_shards, out, device, workers)


def resumed_state(run_dir: Path, steps: int) -> str:
    """``" (resuming at step N)"``, or ``" (trained; evaluating)"`` where the run's ``last.pt``
    has all ``steps`` (a study run again with another ``--pick``): what ``claims`` says of a run
    it finds begun."""
    from sc3d_train.loop.checkpoint import CheckpointError, last_path, load_checkpoint

    try:
        done = int(load_checkpoint(last_path(run_dir))["step"])
    except (CheckpointError, KeyError, TypeError, ValueError):
        return " (resuming)"
    return " (trained; evaluating)" if done >= steps else f" (resuming at step {done})"


def evaluated_on(metrics_file: Path, shards: Path, split: str, data_digest: str | None = None) -> bool:
    """Whether the evaluation in ``metrics_file`` is a finished one (readable JSON, its
    ``predictions.png`` beside it) of ``split`` of ``shards`` as they are now: the same split
    name, folder and ``data_sha256`` (``data_digest``: the shards'
    :func:`~sc3d_train.evaluation.evaluated_data.split_digest`, computed here when None). Else
    it is redone: an evaluation cut short (a kill, a full disk), one of shards re-rendered in
    place since, or one from a version that recorded no digest."""
    try:
        saved = json.loads(Path(metrics_file).read_text())
    except (OSError, ValueError):
        return False
    if not isinstance(saved, dict) or not Path(metrics_file).with_name("predictions.png").is_file():
        return False
    if saved.get("split") != split or Path(saved.get("shards", "")).resolve() != Path(shards).resolve():
        return False
    return saved.get("data_sha256") == (data_digest or split_digest(shards, split))


def run_all(train_shards: Path, eval_shards: Path, out: Path,
            preset: "str | ClaimsPreset" = ClaimsConfig.preset, eval_split: str = ClaimsConfig.eval_split,
            device: str = ClaimsConfig.device, workers: int | None = ClaimsConfig.workers, runs=None,
            echo=print, seeds: int = ClaimsConfig.seeds, pick: str = ClaimsConfig.pick) -> dict:
    """Train and evaluate every run of ``preset`` (or ``runs``) with each of ``seeds`` seeds (skipping
    finished (run, seed) pairs); write the report, with the preset's other runs that ``out`` holds
    finished for every seed. ``seeds`` and ``device`` that cannot serve, and evaluation
    data that cannot serve (of another image size or voxel resolution than the training shards,
    objects trained on or that choose the runs' best.pt, an empty split, shards without voxels)
    is refused before any training. Returns
    ``{run name: aggregate}`` (:func:`aggregate`)."""
    p = PRESETS[preset] if isinstance(preset, str) else preset
    seed_values = check_study_options(p, seeds, device)
    for shards in dict.fromkeys((train_shards, eval_shards)):
        require_complete(Path(shards))
    check_evaluable(train_shards, eval_shards)  # what eval refuses of a checkpoint trained on train_shards
    check_held_out(train_shards, eval_shards, eval_split, p.extra.get("split", _FIT["split"]))
    check_not_selection(train_shards, eval_shards, eval_split, {**_FIT, **p.extra}, pick)
    ShardDataset(eval_shards, eval_split, require_voxels=True).close()  # an empty split, no voxels: refused now
    data_digest = split_digest(eval_shards, eval_split)  # what each finished evaluation must have measured
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    per_seed, timings = {}, {}
    names = list(dict.fromkeys(runs or p.runs))  # a run named twice is one run
    finished = [n for n in p.runs if n not in names and all(  # a rerun with --runs keeps the study's other runs
        evaluated_on(eval_folder(run_folder(out, n, s), pick) / "metrics.json", eval_shards, eval_split, data_digest)
        for s in seed_values)]
    check_study_runs(names + finished, seed_values, p, train_shards, out, device, workers)
    if finished:
        echo(f"also in the report, finished before in {out}: {', '.join(finished)}")
    for name in names + finished:
        per_seed[name] = {}
        for seed in seed_values:
            res, seconds = train_and_evaluate(name, seed, p, train_shards, eval_shards, out, eval_split,
                                              device, workers, pick, echo, data_digest)
            per_seed[name][seed] = res
            timings[f"{name}/seed-{seed}"] = seconds  # None: read back (kept_timings)
    results = {name: aggregate(by_seed) for name, by_seed in per_seed.items()}
    try:  # the reference rows (read no image); without them the report still stands
        results.update(shape_baselines(train_shards, eval_shards, eval_split))
    except DataError as e:
        echo(f"no reference rows: {e}")
    stem = report_stem(pick)
    timings = kept_timings(timings, out / f"{stem}.json", per_seed)
    report = write_report(results, out, stem, preset=asdict(p), seeds=seed_values, pick=pick, eval_split=eval_split,
                          train_shards=str(train_shards), eval_shards=str(eval_shards), timings=timings)
    echo(f"wrote {out / (stem + '.md')}, {out / (stem + '.json')}, {out / (stem + '.png')}")
    echo(report)
    return results
