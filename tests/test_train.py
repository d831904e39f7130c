"""sc3d-train fit on the rendered sample shards: the loss falls and the train-set IoU rises,
resume continues exactly, semi-supervised mode runs both phases, bad input fails early."""
from __future__ import annotations

import csv
import math
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch

from sc3d_cli.train import main
from tests.conftest import TRAINED_RUN_STEPS, assert_learnt, run_cli

TINY = ["--tiny", "--base-channels", "4", "--no-progress", "--log-every", "1"]


def read_csv(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.learnt
def test_fit_writes_the_run_and_learns(trained_run, sample_shards):
    """The shared short run writes every file of a run, logs every step, and learns: its loss
    and its mask loss fall, and its voxels beat the same network untrained (train IoU@0.4 of the
    untrained net: 0.04).

    Spread, 20 runs (seeds 0-9 x torch threads 1 and 2, scripts/test_spread.py, 2-core Xeon,
    2026-11-25): loss last 20 / first 10 steps 0.15-0.25, mask loss 0.25-0.41, train IoU@0.4
    0.27-0.74 (gain over the untrained net 0.23-0.70). Bounds: 0.5, 0.75, 0.15 and 0.10."""
    from sc3d_train.loop.checkpoint_model import build_model, load_model
    from sc3d_train.settings.config import RunConfig
    from sc3d_train.data.dataset import ShardDataset
    from sc3d_train.paper.metrics import predict_dataset, summarize

    for name in ("config.yaml", "metrics.csv", "curves.png", "checkpoints/last.pt",
                 f"checkpoints/step_{TRAINED_RUN_STEPS:06d}.pt",
                 f"checkpoints/step_{TRAINED_RUN_STEPS // 2:06d}.pt"):
        assert (trained_run / name).is_file(), name
    assert list((trained_run / "tb").glob("events.out.tfevents.*"))
    cfg = RunConfig.load(trained_run / "config.yaml")
    assert cfg.model.base_channels == 4 and cfg.model.image_size == 64 and cfg.mode == "supervised"

    rows = read_csv(trained_run / "metrics.csv")
    assert [int(r["step"]) for r in rows] == list(range(TRAINED_RUN_STEPS))
    total = np.array([float(r["total"]) for r in rows])
    assert np.isfinite(total).all()
    assert float(rows[0]["samples_per_s"]) > 0
    assert all(0.0 < float(r["data_wait"]) < 1.0 for r in rows)  # the loop waited for data, not only

    # train-set voxel IoU: trained model vs the same network untrained (eval mode both)
    model, cfg, _ = load_model(trained_run / "checkpoints" / "last.pt")
    ds = ShardDataset(sample_shards, "train", image_size=64)
    torch.manual_seed(0)
    untrained = build_model(cfg).eval()
    # the voxels do not depend on the pose: the head's (no search) is enough and cheaper
    trained_iou = summarize(predict_dataset(model, ds, "cpu", 96, pose_from="head")[0])["overall"]["voxel_iou_0.4"]
    untrained_iou = summarize(predict_dataset(untrained, ds, "cpu", 96, pose_from="head")[0])["overall"]["voxel_iou_0.4"]
    mask_loss = np.array([float(r["l2d"]) for r in rows])
    assert_learnt(("loss, last 20 / first 10 steps", total[-20:].mean() / total[:10].mean(), "<", 0.5),
                  ("mask loss, last 20 / first 10 steps", mask_loss[-20:].mean() / mask_loss[:10].mean(), "<", 0.75),
                  ("train IoU@0.4 gain over the untrained net", trained_iou - untrained_iou, ">", 0.10),
                  ("train IoU@0.4", trained_iou, ">", 0.15))


def interrupt_at(run: Path, copy: Path, step: int) -> None:
    """``copy`` = ``run`` as if it had been killed right after the checkpoint of ``step``: later
    checkpoints gone, ``last.pt`` that checkpoint, and a metrics row written after it (which resume
    must drop)."""
    shutil.copytree(run, copy)
    ckpts = copy / "checkpoints"
    for f in ckpts.glob("step_*.pt"):
        if int(f.stem.split("_")[1]) > step:
            f.unlink()
    shutil.copy(ckpts / f"step_{step:06d}.pt", ckpts / "last.pt")
    rows = read_csv(run / "metrics.csv")
    with open(copy / "metrics.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0].keys()))
        w.writeheader()
        w.writerows(r for r in rows if int(r["step"]) < step)
        w.writerow({**rows[step], "total": "999"})


def test_the_done_line_gives_the_median_rate_of_the_loop(sample_shards, tmp_path):
    """``fit``'s last line gives the median of the logged intervals' samples/s, the first
    (compiling, first batches) left out, not the last interval's: computed here from
    ``metrics.csv`` with ``statistics.median``."""
    import re
    import statistics

    res = run_cli(main, ["fit", "--shards", sample_shards, "--out", tmp_path / "run", "--steps", 7,
                         "--batch-size", 2, *TINY, "--val-every", 0])
    rates = [float(r["samples_per_s"]) for r in read_csv(tmp_path / "run" / "metrics.csv")]
    said = float(re.search(r"done: step 7, ([0-9.]+) samples/s", res.output).group(1))
    assert said == pytest.approx(statistics.median(rates[1:]), abs=0.06), (said, rates)


def test_curves_are_drawn_at_most_once_a_minute_and_at_the_end(tmp_path, monkeypatch):
    """``MetricsLog.draw_curves``: the first checkpoint draws ``curves.png``; one within
    CURVES_EVERY_S of it does not (the file, removed, stays away); the run's last does; and once
    the interval has passed (the clock moved past it) the next checkpoint draws again."""
    import sc3d_train.loop.metrics_log as metrics_log

    log = metrics_log.MetricsLog(tmp_path, 0)
    for step in range(9, 40, 10):
        log.log(step, {"phase": "supervised", "total": 1.0 / step, "samples_per_s": 100.0})
    png = tmp_path / "curves.png"
    assert log.draw_curves(png) and png.stat().st_size > 0
    png.unlink()
    assert not log.draw_curves(png) and not png.exists()
    assert log.draw_curves(png, final=True) and png.is_file()
    png.unlink()
    clock = metrics_log.time.monotonic() + metrics_log.CURVES_EVERY_S + 1
    monkeypatch.setattr(metrics_log.time, "monotonic", lambda: clock)
    assert log.draw_curves(png) and png.is_file()
    log.close()


def test_gpu_utilisation_is_read_at_most_every_five_seconds_and_never_off_cuda():
    """``GpuUtilisation``: on CUDA the first log reads the utilisation; logs within ``every_s``
    of that read log the same value without reading again; the first log after it reads anew.
    A reader that fails (no NVML) gives None. On the CPU nothing is read at all. The reader here
    is a list of values with a counter (NVML does not run on this machine); the clock is a list
    of seconds."""
    from sc3d_train.loop.metrics_log import GpuUtilisation

    values, reads = iter([0.40, 0.90]), []
    clock = [100.0]

    def read():
        reads.append(clock[0])
        return next(values)

    probe = GpuUtilisation(torch.device("cuda", 0), every_s=5.0, read=read, clock=lambda: clock[0])
    seen = []
    for t in (100.0, 101.0, 104.9, 105.0, 107.0):
        clock[0] = t
        seen.append(probe())
    assert seen == [0.40, 0.40, 0.40, 0.90, 0.90] and reads == [100.0, 105.0]
    assert GpuUtilisation(torch.device("cuda", 0), read=lambda: 1 / 0)() is None
    assert GpuUtilisation(torch.device("cpu"), read=lambda: 1 / 0)() is None


def test_resume_equals_uninterrupted(sample_shards, tmp_path):
    args = ["--shards", sample_shards, "--batch-size", "4", *TINY, "--checkpoint-every", "3", "--seed", "5"]
    whole, parts = tmp_path / "whole", tmp_path / "parts"
    run_cli(main, ["fit", "--out", whole, "--steps", "6", *args])
    interrupt_at(whole, parts, 3)
    # resumed with 2 loader worker processes: the samples must be the same as in-process; the lr
    # follows the same cosine schedule (hand-derived: 1e-3 * (0.1 + 0.9 * (1 + cos(pi k / 6)) / 2))
    result = run_cli(main, ["fit", "--out", parts, "--steps", "6", "--resume", "--no-progress",
                            "--workers", "2"])
    assert "step 6" in result.output
    a, b = read_csv(whole / "metrics.csv"), read_csv(parts / "metrics.csv")
    assert [r["step"] for r in b] == [str(i) for i in range(6)]
    expected_lr = [1e-3 * (0.1 + 0.9 * (1 + math.cos(math.pi * k / 6)) / 2) for k in range(6)]
    assert [float(r["lr"]) for r in b] == pytest.approx(expected_lr, rel=1e-9)
    for ra, rb in zip(a, b):
        for key in ("total", "l3d", "l2d", "lsc", "kl", "pose"):
            assert ra[key] == rb[key], (ra["step"], key, ra[key], rb[key])  # bit-identical
    wa = torch.load(whole / "checkpoints" / "last.pt", weights_only=False)["model"]
    wb = torch.load(parts / "checkpoints" / "last.pt", weights_only=False)["model"]
    assert all(torch.equal(wa[k], wb[k]) for k in wa)

    # a resumed run may not change what decides the trajectory
    bad = run_cli(main, ["fit", "--out", parts, "--shards", sample_shards, "--steps", "8",
                         "--resume", "--seed", "6"], expect_exit=1)
    assert "cannot change on --resume" in bad.output and "--seed" in bad.output
    again = run_cli(main, ["fit", "--out", parts, "--shards", sample_shards, "--steps", "8"], expect_exit=1)
    assert "already holds a run" in again.output


def test_semi_supervised_runs_both_phases(sample_shards, tmp_path):
    from sc3d_train.data.dataset import ShardDataset

    out = tmp_path / "semi"
    run_cli(main, ["fit", "--shards", sample_shards, "--out", out, "--steps", "4", "--batch-size", "4",
                   *TINY, "--semi", "--labeled-fraction", "0.15", "--pretrain-steps", "2"])
    rows = read_csv(out / "metrics.csv")
    assert [r["phase"] for r in rows] == ["supervised"] * 2 + ["unsupervised"] * 2
    # --semi-lr defaults to --lr; the cosine schedule restarts with each phase (2 steps each:
    # 1e-3, then 1e-3 * (0.1 + 0.9 * (1 + cos(pi / 2)) / 2) = 5.5e-4)
    assert [float(r["lr"]) for r in rows] == pytest.approx([1e-3, 5.5e-4, 1e-3, 5.5e-4])
    # pre-training logs no unlabelled terms; the mixed phase logs what it optimises: the labelled
    # half's L_3D / L_2D / pose and the unlabelled half's L_sc and pose search (u_*)
    assert all(r["u_lsc"] == "" for r in rows[:2])
    for r in rows[2:]:
        assert float(r["l3d"]) > 0.1 and float(r["u_lsc"]) > 0 and float(r["u_pose"]) > 0
    # a checkpoint at the phase boundary, the labelled objects listed
    assert (out / "checkpoints" / "step_000002.pt").is_file()
    listed = (out / "labeled_objects.txt").read_text().split()

    # the labelled subset: chosen by object, stratified by category (every category of the
    # training split has max(1, round(0.15 n_c)) labelled objects), seeded, disjoint from the rest
    lab = ShardDataset(sample_shards, "train", subset="labeled", labeled_fraction=0.15, seed=0)
    unl = ShardDataset(sample_shards, "train", subset="unlabeled", labeled_fraction=0.15, seed=0,
                       require_voxels=False)
    allt = ShardDataset(sample_shards, "train")
    per_cat = {}
    for o in allt.objects:
        per_cat[o.category] = per_cat.get(o.category, 0) + 1
    lab_cat = {}
    for o in lab.objects:
        lab_cat[o.category] = lab_cat.get(o.category, 0) + 1
    assert lab_cat == {c: max(1, round(0.15 * n)) for c, n in per_cat.items()}
    assert sorted(listed) == sorted(f"{o.category}/{o.model_id}" for o in lab.objects)
    assert lab.num_objects + unl.num_objects == allt.num_objects
    assert not {o.model_id for o in lab.objects} & {o.model_id for o in unl.objects}
    again = ShardDataset(sample_shards, "train", subset="labeled", labeled_fraction=0.15, seed=0)
    assert [o.model_id for o in again.objects] == [o.model_id for o in lab.objects]

    only = tmp_path / "labeled_only"
    run_cli(main, ["fit", "--shards", sample_shards, "--out", only, "--steps", "1", "--batch-size", "2",
                   *TINY, "--labeled-only"])
    assert read_csv(only / "metrics.csv")[0]["phase"] == "supervised"


def test_fit_refuses_the_test_split(sample_shards, tmp_path):
    r = run_cli(main, ["fit", "--shards", sample_shards, "--out", tmp_path / "t", "--steps", "1",
                       "--batch-size", "2", *TINY, "--split", "test"], expect_exit=1)
    assert "refusing to train on the test split" in r.output
    assert not (tmp_path / "t" / "checkpoints").exists()


def test_loader_masks_follow_the_camera(sample_shards):
    """The 48 px masks come from the 64 px masks, and K_sc is K scaled by 3/4."""
    from sc3d_train.data.dataset import ShardDataset
    from sc3d_train.data.loader import ViewSampler

    ds = ShardDataset(sample_shards, "train")
    item = ds[5]
    assert item["masks_sc"].shape == (48, 48) and item["images"].shape == (3, 64, 64)
    assert torch.allclose(item["K_sc"][:2], item["K"][:2] * 0.75)
    frac64, frac48 = item["masks"].mean(), item["masks_sc"].mean()
    assert frac48 > 0 and abs(frac64 - frac48) < 0.02
    # the view stream is a pure function of (seed, position)
    s = ViewSampler(ds.num_objects, ds.num_views, seed=3)
    it = iter(s)
    first = [next(it) for _ in range(30)]
    it2 = iter(ViewSampler(ds.num_objects, ds.num_views, seed=3, start=11))
    assert [next(it2) for _ in range(19)] == first[11:]
    ranks = [ViewSampler(ds.num_objects, ds.num_views, seed=3, rank=r, world_size=2).epoch_indices(0)
             for r in (0, 1)]
    assert set(ranks[0]) | set(ranks[1]) >= set(s.epoch_indices(0))


def test_bad_inputs_fail_before_training(sample_shards, tmp_path):
    base = ["fit", "--out", tmp_path / "run", "--steps", "2", "--batch-size", "2", *TINY]
    no_vox = tmp_path / "no_voxels"
    shutil.copytree(sample_shards, no_vox)
    shard = sorted(no_vox.glob("shard-*.h5"))[0]
    with h5py.File(shard, "a") as f:
        del f["voxels"]
    r = run_cli(main, base + ["--shards", no_vox], expect_exit=1)
    assert "voxels" in r.output and "voxelize" in r.output
    r = run_cli(main, base + ["--shards", sample_shards, "--split", "nosuch"], expect_exit=1)
    assert "split 'nosuch' is empty" in r.output
    r = run_cli(main, base + ["--shards", tmp_path / "missing"], expect_exit=1)
    assert "does not exist" in r.output
    assert not (tmp_path / "run" / "checkpoints").exists()


def test_a_broken_shard_is_named_in_one_line_with_and_without_loader_workers(sample_shards, tmp_path):
    """A flipped byte inside an image chunk of an unlabelled training object of a ``--semi`` run
    (HDF5's Fletcher-32 check fails; only the loader reads that object: the pose targets read
    the labelled ones, and a loader with workers reads item 0 in the main process to size its
    ring, so not object 0): ``fit`` stops with exit code 1 and the same one line naming the shard
    file, the row, the problem and the object, with ``--workers 0`` (read in the main process)
    and ``--workers 2`` (read in a loader worker; before issue 23 the line was PyTorch's "Caught
    DataError in DataLoader worker process N" followed by the worker's traceback)."""
    from sc3d_train.data.dataset import ShardDataset

    bad = tmp_path / "bad"
    shutil.copytree(sample_shards, bad)
    ref = ShardDataset(bad, "train", subset="unlabeled", labeled_fraction=0.5, seed=0,
                       require_voxels=False).objects[-1]
    with h5py.File(ref.shard) as f:
        chunk = f["images"].id.get_chunk_info_by_coord((ref.row, 5, 0, 0, 0))
    with open(ref.shard, "r+b") as fh:
        fh.seek(chunk.byte_offset + chunk.size // 2)
        byte = fh.read(1)
        fh.seek(chunk.byte_offset + chunk.size // 2)
        fh.write(bytes([byte[0] ^ 0xFF]))
    with h5py.File(ref.shard) as f, pytest.raises(OSError) as hdf5:  # HDF5's own words for it
        f["images"][ref.row, 5]
    expected = (f"Error: {ref.shard}: row {ref.row} cannot be read ({hdf5.value}); see `sc3d-data info "
                f"--verify` (object {ref.model_id})")
    for workers in (0, 2):
        r = run_cli(main, ["fit", "--shards", bad, "--out", tmp_path / f"run{workers}", "--steps", "6",
                           "--batch-size", "4", *TINY, "--semi", "--labeled-fraction", "0.5",
                           "--pretrain-steps", "0", "--seed", "0", "--workers", workers, "--val-every", 0],
                    expect_exit=1)
        assert r.output.splitlines()[1:] == [expected], (workers, r.output)


def test_nan_loss_stops_with_step_and_checkpoint(sample_shards, tmp_path):
    """Weights corrupted with NaN in the checkpoint: the resumed run stops and names its first
    step (the loss is read back every --log-every steps, here after steps 2 and 3: the message
    still names step 2) and the last good checkpoint; no checkpoint is written after it."""
    out = tmp_path / "nan"
    run_cli(main, ["fit", "--shards", sample_shards, "--out", out, "--steps", "2", "--batch-size", "2", *TINY])
    last = out / "checkpoints" / "last.pt"
    ckpt = torch.load(last, weights_only=False)
    for v in ckpt["model"].values():
        if v.is_floating_point():
            v.fill_(float("nan"))
    torch.save(ckpt, last)
    r = run_cli(main, ["fit", "--out", out, "--steps", "6", "--resume", "--no-progress", "--log-every", "4",
                       "--checkpoint-every", "5"], expect_exit=1)
    assert "at step 2" in r.output and "last good checkpoint" in r.output and "last.pt" in r.output
    assert sorted(p.name for p in (out / "checkpoints").glob("step_*.pt")) == ["step_000002.pt"]


#: the ``sc3d-train`` console script (``console_main``) with an ``atexit`` hook that marks, per rank,
#: a finalised interpreter in the folder ``SC3D_TEST_FINALISED`` names
RANK_SCRIPT = """import atexit, os, sys
atexit.register(lambda: open(os.path.join(os.environ["SC3D_TEST_FINALISED"], "rank" + os.environ["RANK"]), "w").close())
sys.argv[0] = "sc3d-train"
from sc3d_cli.train import console_main
console_main()
"""


def _torchrun_fit(*args) -> str:
    """stdout of ``sc3d-train fit`` under torchrun with 2 CPU ranks (gloo; ``--device cpu`` also on a
    GPU machine: on one with a single GPU the default ``auto`` would give rank 1 a ``cuda:1`` that
    does not exist), batch 4, the tiny network, ``args`` after; asserts exit 0 within 300 s, and that
    no rank went through Python's finalisation: the console script leaves a process group's rank with
    ``os._exit`` (``cli/interrupted_exit.py``; DDP keeps the group's gloo threads alive into the
    finalisation, where a finished rank rarely aborted, failing the job)."""
    import os
    import subprocess
    import sys
    import tempfile

    repo = Path(__file__).resolve().parents[1]
    with tempfile.TemporaryDirectory() as folder:
        script, finalised = Path(folder) / "sc3d_train_rank.py", Path(folder) / "finalised"
        script.write_text(RANK_SCRIPT)
        finalised.mkdir()
        # --standalone: torchrun binds a free port itself (picking one here and handing it over
        # raced with other processes taking it in between)
        cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
               str(script), "fit", "--device", "cpu", "--batch-size", "4", *TINY, *map(str, args)]
        env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(repo), "SC3D_TEST_FINALISED": str(finalised)}
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=env, cwd=repo)
        assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-3000:]
        assert not any(finalised.iterdir()), sorted(p.name for p in finalised.iterdir())
    return r.stdout


def test_ddp_validation_between_logs_and_checkpoints_does_not_hang(sample_shards, tmp_path):
    """Only rank 0 validates, but every rank must join the loss check made before a validation
    (a collective): with ``--val-every 3`` against logs and checkpoints every 4 steps, rank 0
    alone called it at step 3, the other rank went on into the next step's gradient all-reduce,
    and the run hung (found by a review; the default intervals, 10 and 100, line up). The run
    must end (the timeout of 300 s fails it) with its validation of step 3 written."""
    out = tmp_path / "run"
    _torchrun_fit("--shards", sample_shards, "--out", out, "--steps", 4, "--log-every", 4,
                  "--checkpoint-every", 4, "--val-every", 3)
    assert [int(r["step"]) for r in read_csv(out / "validation.csv")] == [3, 4]


def test_ddp_two_cpu_ranks_supervised_then_semi_keep_the_same_weights(sample_shards, tmp_path):
    """torchrun with 2 processes (gloo on the CPU, ``--device cpu`` also on a GPU machine: on one
    with a single GPU the default ``auto`` would give rank 1 a ``cuda:1`` that does not exist)
    and the same command, a ``--semi`` run: 2 supervised steps, then 2 mixed steps whose
    unlabelled pass runs outside the DDP wrapper (``phase_step.step_losses``). The run completes,
    so at each checkpoint (steps 2 and 4) both ranks held the same weights
    (``runtime.check_same_weights`` stops the run otherwise: with both passes outside the wrapper
    it stopped at step 4); only rank 0 reports and writes, and the checkpoint holds both ranks'
    RNG states and the mixed phase's data position. (Exact resume under DDP was checked by hand:
    2 steps + --resume to 4 logs the losses of 4 steps at once; one launch here keeps the suite's
    time budget.)"""
    def torchrun(*args):
        return _torchrun_fit("--checkpoint-every", "2", *args)

    whole = tmp_path / "whole"
    out = torchrun("--shards", sample_shards, "--out", whole, "--steps", 4,
                   "--semi", "--labeled-fraction", "0.5", "--pretrain-steps", 2)
    assert out.count("done: step 4") == 1  # only rank 0 reports
    rows = read_csv(whole / "metrics.csv")
    assert [(int(r["step"]), r["phase"]) for r in rows] == [(0, "supervised"), (1, "supervised"),
                                                            (2, "unsupervised"), (3, "unsupervised")]
    assert all(np.isfinite(float(r["total"])) for r in rows)
    assert all(np.isfinite(float(r["u_lsc"])) for r in rows[2:])  # the unlabelled pass ran
    ckpt = torch.load(whole / "checkpoints" / "last.pt", weights_only=False)
    assert len(ckpt["rng"]) == 2 and ckpt["step"] == 4
    # per rank, 2 mixed steps of 1 labelled + 1 unlabelled image (batch 4 over 2 ranks, share 0.5)
    assert ckpt["data_position"] == {"phase": "unsupervised", "phase_start": 2, "samples_per_rank": 2,
                                     "labeled_samples_per_rank": 2}
    assert (whole / "checkpoints" / "step_000002.pt").is_file()


def _check_weights_on_rank(rank: int, store: str, results: str) -> None:
    """One rank of :func:`test_check_same_weights_names_the_rank_and_the_parameter_that_differ`."""
    import torch.distributed as dist

    from sc3d_train.loop.runtime import DistInfo, RanksDiverged, check_same_weights

    torch.set_num_threads(1)
    dist.init_process_group("gloo", init_method=f"file://{store}", rank=rank, world_size=2)
    try:
        torch.manual_seed(0)
        model = torch.nn.Sequential(torch.nn.Linear(3, 4), torch.nn.Linear(4, 2))
        info = DistInfo(rank, 2, rank)
        check_same_weights(model, info, 1)  # the same seed: the same weights, no error
        if rank == 1:
            with torch.no_grad():
                model[1].bias[0] += 1e-6  # far below one Adam step at lr 1e-3
        try:
            check_same_weights(model, info, 2)
            message = "no error"
        except RanksDiverged as e:
            message = str(e)
        Path(f"{results}.{rank}").write_text(message)
    finally:
        dist.destroy_process_group()


def test_check_same_weights_names_the_rank_and_the_parameter_that_differ(tmp_path):
    """Two gloo processes with the same weights pass; after rank 1 moves one bias by 1e-6, both
    ranks raise, naming rank 1, the step and the parameter."""
    import torch.multiprocessing as mp

    mp.start_processes(_check_weights_on_rank, args=(str(tmp_path / "store"), str(tmp_path / "result")), nprocs=2,
                       start_method="fork")  # forked: no second import of torch
    expected = ("after step 2 rank(s) [1] hold weights that differ from rank 0's in 1 of 4 parameter tensors "
                "(first: 1.bias): a gradient was not averaged across ranks")
    assert [(tmp_path / f"result.{r}").read_text() for r in (0, 1)] == [expected, expected]


def test_semi_resume_across_the_phase_boundary_equals_uninterrupted(sample_shards, tmp_path):
    """Both streams of the mixed phase (labelled and unlabelled) resume where they stopped, with
    ``--augment``: its draws follow (seed, step), so the resumed images are the same too."""
    args = ["--shards", sample_shards, "--batch-size", "4", *TINY, "--semi", "--labeled-fraction", "0.5",
            "--pretrain-steps", "2", "--checkpoint-every", "3", "--seed", "3", "--augment"]
    whole, parts = tmp_path / "whole", tmp_path / "parts"
    run_cli(main, ["fit", "--out", whole, "--steps", "5", *args])
    interrupt_at(whole, parts, 3)
    run_cli(main, ["fit", "--out", parts, "--steps", "5", "--resume", "--no-progress"])
    a, b = read_csv(whole / "metrics.csv"), read_csv(parts / "metrics.csv")
    assert [r["phase"] for r in a] == ["supervised"] * 2 + ["unsupervised"] * 3
    assert len(a) == len(b) == 5
    for ra, rb in zip(a, b):
        for key in ("total", "l3d", "u_lsc", "u_pose"):
            assert ra[key] == rb[key], (ra["step"], key, ra[key], rb[key])
        assert math.isfinite(float(ra["total"]))


def test_unlabelled_pass_leaves_batchnorm_running_statistics_alone():
    """The unlabelled pass of the semi phase normalises with its own batch statistics (train
    mode) but does not move the running statistics that eval uses."""
    from sc3d_train.settings.config import ModelConfig
    from sc3d_train.paper.model import SelfConsistencyNet
    from sc3d_train.loop.phase_step import frozen_batchnorm_statistics

    torch.manual_seed(0)
    model = SelfConsistencyNet(ModelConfig.tiny()).train()
    bn = model.encoder.stem[1]
    before = (bn.running_mean.clone(), bn.running_var.clone(), int(bn.num_batches_tracked))
    x = torch.rand(4, 3, 64, 64) * 5 + 3  # far from the running statistics (0 mean, 1 var)
    with frozen_batchnorm_statistics(model):
        out = model(x)
    assert torch.equal(bn.running_mean, before[0]) and torch.equal(bn.running_var, before[1])
    assert int(bn.num_batches_tracked) == before[2] and bn.momentum == 0.1
    model(x)  # outside the context the running statistics move
    assert not torch.equal(bn.running_mean, before[0])
    assert out.voxel_logits.shape == (4, 32, 32, 32)


def test_data_wait_clock_counts_the_time_next_blocks():
    """A loader that takes 30 ms per batch, consumed by a loop that spends 20 ms per step: the
    clock must show 3 x 30 ms of waiting (and nothing of the loop's own time)."""
    import time

    from sc3d_train.loop.metrics_log import DataWaitClock

    def slow():
        for i in range(3):
            time.sleep(0.03)
            yield i

    clock = DataWaitClock()
    for _ in clock.wrap(slow()):
        time.sleep(0.02)
    assert clock.seconds == pytest.approx(0.09, abs=0.015)
