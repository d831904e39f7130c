"""Does one training step of the run's batch fit in the CPU's memory? Measured before training.

On a CPU a step that does not fit is not an exception: Linux's out-of-memory killer ends the
process with no message (``fit --batch-size 100000`` did). So before a CPU run whose batch is
larger than :data:`PROBE_ABOVE` samples per rank, :func:`check_cpu_batch_fits` runs the step's
forward and backward pass on a copy of the network at two small batches, counts the bytes of
the tensors alive at its peak (:class:`LiveTensorBytes`, a ``TorchDispatchMode`` that adds every
new storage and subtracts it when it is freed: exact, and independent of what the allocator
happens to hold already, unlike the process's resident memory) and extrapolates linearly to the
run's batch. A batch whose step would need more than :data:`USABLE_SHARE` of the memory
available (``MemAvailable``, and what the cgroup's limit leaves: a SLURM job's memory, a
container's) is refused in one line that names the largest batch that fits. The copy leaves the run's network, its BatchNorm statistics and every RNG as they were.
On CUDA nothing is probed: an allocation that does not fit raises ``torch.OutOfMemoryError``,
which ``fit`` reports in one line.

Measured (2026-11-26, 2-core AMD EPYC): the tiny network's supervised step needs about 10 MiB a
sample (``/usr/bin/time`` peak RSS of ``fit --tiny --steps 2`` at batch 32 and 256: 0.86 and
2.9 GiB), so 64 samples stay below 1 GiB at that width.
"""
from __future__ import annotations

import copy
import weakref
from pathlib import Path

import torch
from torch.utils import _pytree as pytree
from torch.utils._python_dispatch import TorchDispatchMode

#: CPU batches (per rank) up to this many samples are trained without probing
PROBE_ABOVE = 64
#: the two batch sizes whose peak memory is extrapolated
PROBE_SIZES = (4, 16)
#: share of the available memory a step may plan to use (the allocator holds about 10% more than
#: the live tensors: 10 MiB a sample resident against 8.9 MiB counted, tiny network)
USABLE_SHARE = 0.8
#: share of what fits that the refusal suggests
SUGGESTED_SHARE = 0.9
GIB, MIB = 2**30, 2**20


#: (mount, limit file, usage file, the reclaimable page cache's key in memory.stat) of the cgroup
#: memory controller, v2 then v1
_CGROUP_FILES = (("/sys/fs/cgroup", "memory.max", "memory.current", "inactive_file"),
                 ("/sys/fs/cgroup/memory", "memory.limit_in_bytes", "memory.usage_in_bytes", "total_inactive_file"))


def _stat_value(path: Path, key: str) -> int:
    """The ``KEY N`` value of a cgroup ``memory.stat`` file, 0 where it is not there."""
    try:
        for line in path.read_text().splitlines():
            name, _, value = line.partition(" ")
            if name == key:
                return int(value)
    except (OSError, ValueError):
        pass
    return 0


def cgroup_free_bytes() -> int | None:
    """What the memory limits of this process's cgroup and its ancestors leave (limit less usage,
    the least over the levels; the usage without the inactive page cache, which the kernel
    reclaims before it kills: as docker and the kubelet count it), bytes: a SLURM job or a
    container limits a process below the machine's free memory. None where no level sets a
    limit. cgroup v2 and v1."""
    try:
        lines = Path("/proc/self/cgroup").read_text().splitlines()
    except OSError:
        return None
    paths = {}
    for line in lines:
        _, controllers, path = line.split(":", 2)
        if controllers == "":
            paths.setdefault("/sys/fs/cgroup", path)
        elif "memory" in controllers.split(","):
            paths["/sys/fs/cgroup/memory"] = path
    free = None
    for mount, limit_name, usage_name, cache_key in _CGROUP_FILES:
        folder = Path(mount) / paths.get(mount, "/").lstrip("/")
        for level in [folder, *folder.parents]:
            if not level.is_relative_to(mount):
                break
            try:
                limit = (level / limit_name).read_text().strip()
                usage = int((level / usage_name).read_text()) - _stat_value(level / "memory.stat", cache_key)
            except (OSError, ValueError):
                continue
            if limit.isdigit() and int(limit) < 2**60:  # "max" (v2) or a huge number (v1): no limit
                free = min(free if free is not None else 2**63, int(limit) - usage)
    return free


def available_bytes() -> int | None:
    """Memory this process may still take, bytes: the machine's available memory (psutil; Linux's
    ``MemAvailable``), lowered to what its cgroup's limit leaves (:func:`cgroup_free_bytes`).
    None where neither is known."""
    import psutil

    try:
        machine = int(psutil.virtual_memory().available)
    except (OSError, RuntimeError, AttributeError):  # no memory figures on this system
        machine = None
    free = [v for v in (machine, cgroup_free_bytes()) if v is not None]
    return min(free) if free else None


class LiveTensorBytes(TorchDispatchMode):
    """Inside: ``live`` is the number of bytes of the tensor storages created inside and still
    alive, ``peak`` its largest value (autograd's backward ops included)."""

    def __init__(self):
        super().__init__()
        self.live = self.peak = 0
        self._sizes: dict[int, int] = {}

    def _freed(self, key: int) -> None:
        self.live -= self._sizes.pop(key, 0)

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        out = func(*args, **(kwargs or {}))
        for value in pytree.tree_leaves(out):
            if isinstance(value, torch.Tensor):
                storage = value.untyped_storage()
                key, size = storage.data_ptr(), storage.nbytes()
                if size and key not in self._sizes:
                    self._sizes[key] = size
                    self.live += size
                    self.peak = max(self.peak, self.live)
                    weakref.finalize(storage, self._freed, key)
        return out


def step_peak_bytes(t, batch_size: int) -> int:
    """Bytes of the tensors alive at the peak of one forward and backward pass of ``t``'s step at
    ``batch_size`` samples (``t``: :class:`~sc3d_train.loop.trainer.Training`), its input batch
    not counted: on a copy of the network, with every torch RNG restored afterwards. A ``semi``
    run measures its mixed step (both passes)."""
    from sc3d_train.data.loader import make_loader
    from sc3d_train.loop.phase_step import step_losses, training_batch
    from sc3d_train.loop.schedule import batch_split
    from sc3d_train.paper.pose import PoseGrid

    cfg = t.cfg
    sizes = {"supervised": batch_size}
    if cfg.mode == "semi" and "unlabeled" in t.datasets:
        n_lab, n_unl = batch_split(cfg, batch_size)
        sizes = {"supervised": n_lab, "unsupervised": n_unl} if n_lab else {"unsupervised": n_unl}
    datasets = {"supervised": t.labeled, "unsupervised": t.datasets.get("unlabeled")}
    as_phase = {"supervised": "true-pose-masks"} if cfg.mode == "true-pose-masks" else {}  # as the loop does
    batches = {phase: training_batch(next(iter(make_loader(datasets[phase], n, seed=0))), as_phase.get(phase, phase),
                                     t.device, t.channels_last, t.pose_targets)
               for phase, n in sizes.items()}
    model = copy.deepcopy(t.model)
    with torch.random.fork_rng(devices=[]), LiveTensorBytes() as memory:
        losses = step_losses(batches, model, model, cfg.mode, cfg.loss_weights, PoseGrid.of(cfg.model))
        losses["total"].backward()
    return memory.peak


def check_cpu_batch_fits(t):
    """``t`` (a :class:`~sc3d_train.loop.trainer.Training`), after raising ``ValueError`` when one
    step of ``t.local_batch`` samples, times the ranks of this machine (torchrun's
    ``LOCAL_WORLD_SIZE``), would need more memory than is available (module doc). Checks nothing
    on CUDA, for batches up to :data:`PROBE_ABOVE`, or where Linux does not report the memory
    available."""
    from sc3d_train.loop.schedule import mixed_batch

    largest = max(t.local_batch, mixed_batch(t.cfg, t.local_batch) if t.cfg.mode == "semi" else 0)
    if t.device.type != "cpu" or largest <= PROBE_ABOVE or (free := available_bytes()) is None:
        return t
    ranks_here = t.dist.local_world_size
    small, large = PROBE_SIZES
    peaks = [step_peak_bytes(t, n) for n in (small, large)]
    per_sample = max((peaks[1] - peaks[0]) / (large - small), 1.0)
    fixed = max(peaks[0] - small * per_sample, 0.0)
    need = ranks_here * (fixed + per_sample * largest)
    usable = USABLE_SHARE * free
    if need > usable:
        # the suggestion keeps a tenth in reserve: the memory available moves from one run to the next
        most = int(SUGGESTED_SHARE * (usable / ranks_here - fixed) // per_sample) * t.dist.world_size
        option, size = ("--semi-batch-size", t.cfg.semi_batch_size) if largest > t.local_batch else \
            ("--batch-size", t.cfg.batch_size)
        advice = f"use {option} {most} or less" if most >= 1 else "not even a batch of 1 fits: free memory first"
        raise ValueError(
            f"{option} {size} needs about {need / GIB:.1f} GiB of memory a step on the CPU "
            f"({per_sample / MIB:.1f} MiB a sample, measured), more than the {usable / GIB:.1f} GiB a step may take "
            f"({USABLE_SHARE:.0%} of the {free / GIB:.1f} GiB available); {advice}")
    return t
