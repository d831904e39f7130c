"""Where a training process runs: torchrun ranks, the device, mixed precision, seeds, the few
collective operations the loop needs (no-ops on one process) and the check that every rank
holds the same weights (:func:`check_same_weights`)."""
from __future__ import annotations

import atexit
import dataclasses
import os
import random
import re
from dataclasses import dataclass

import numpy as np
import torch

from sc3d_train.settings.config import DEVICE_HELP, RunConfig

#: environment variable naming what ``--device auto`` picks on this machine: ``cpu`` or ``cuda``
#: (unset or empty: CUDA when torch sees a GPU, else the CPU). The test suite sets ``cpu``
#: (``tests/conftest.py``) so that its CPU tests train on the CPU on a GPU machine too.
AUTO_DEVICE_ENV = "SC3D_AUTO_DEVICE"


@dataclass
class DistInfo:
    rank: int = 0
    world_size: int = 1
    local_rank: int = 0
    #: ranks on this machine (torchrun's ``LOCAL_WORLD_SIZE``): they share its cores and memory
    local_world_size: int = 1

    @property
    def is_main(self) -> bool:
        return self.rank == 0


def setup_distributed(device_name: str) -> DistInfo:
    """Join the torchrun process group when ``WORLD_SIZE > 1`` (NCCL on CUDA, else gloo)."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return DistInfo()
    import torch.distributed as dist

    info = DistInfo(int(os.environ["RANK"]), world, int(os.environ.get("LOCAL_RANK", "0")),
                    int(os.environ.get("LOCAL_WORLD_SIZE", "1")))
    if not dist.is_initialized():
        kind = auto_device() if device_name == "auto" else device_name
        use_cuda = torch.cuda.is_available() and kind != "cpu"
        dist.init_process_group("nccl" if use_cuda else "gloo")
        atexit.register(teardown_distributed)  # once, when this process exits (several fits may share the group)
        _JOINED.append(True)
    return info


#: not empty once :func:`setup_distributed` joined a process group in this process
_JOINED: list[bool] = []


def joined_process_group() -> bool:
    """Whether :func:`setup_distributed` joined a torchrun process group in this process (left or
    not): the console script then leaves without finalising (``cli/interrupted_exit.py``)."""
    return bool(_JOINED)


def teardown_distributed() -> None:
    """Leave the process group :func:`setup_distributed` joined, if any (registered with
    ``atexit`` there). A rank that exits with its gloo group still alive can abort in the
    group's threads at interpreter exit ("terminate called without an active exception")."""
    import torch.distributed as dist

    if dist.is_available() and dist.is_initialized():
        dist.destroy_process_group()


class PeerStopped(OSError):
    """This rank's collective lost another torchrun rank, which stopped on its own error (a killed
    loader worker, a shard it could not read) and printed it: gloo's ``RuntimeError`` here ended
    the healthy rank in a traceback after that one-line error; an OSError is one line (``fit``)."""


#: what gloo raises in a rank whose peer's process ended during a collective
PEER_GONE = ("Connection closed by peer", "Connection reset by peer")


def peer_stopped(e: BaseException, then: str = "") -> PeerStopped | None:
    """``e`` as a :class:`PeerStopped` (followed by ``then``, e.g. the last good checkpoint) where it
    is gloo's report that another rank ended mid-collective; None for any other error."""
    gone = next((s for s in PEER_GONE if s in str(e)), None) if isinstance(e, RuntimeError) else None
    if gone is None:
        return None
    return PeerStopped(f"another rank stopped during this step (gloo: {gone}): its error is above"
                       f"{'; ' + then if then else ''}")


def auto_device() -> str:
    """``cpu`` or ``cuda``: what ``--device auto`` means here (:data:`AUTO_DEVICE_ENV`, else CUDA
    when torch sees a GPU). ``ValueError`` naming the variable when it is set to anything else."""
    pick = os.environ.get(AUTO_DEVICE_ENV, "").strip()
    if pick not in ("", "cpu", "cuda"):
        raise ValueError(f"{AUTO_DEVICE_ENV}={pick!r}: --device auto can mean cpu or cuda (unset: CUDA if present)")
    has_cuda = torch.cuda.is_available()
    if pick == "cuda" and not has_cuda:
        raise ValueError(f"{AUTO_DEVICE_ENV}=cuda: CUDA is not available here (torch sees no GPU); unset it "
                         f"or use --device cpu")
    return pick or ("cuda" if has_cuda else "cpu")


def check_device_name(name: str) -> None:
    """``ValueError`` naming ``--device`` when ``name`` is none of auto, cpu, cuda, cuda:N, or asks
    for CUDA where torch sees none (no side effect: callable before a run says it starts)."""
    if not re.fullmatch(r"auto|cpu|cuda(:\d+)?", name):
        raise ValueError(f"--device {name!r}: not a device; use {DEVICE_HELP}")
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise ValueError(f"--device {name}: CUDA is not available here (torch sees no GPU); use --device cpu or auto")


def resolve_device(name: str, dist: DistInfo | None = None) -> torch.device:
    """The device of ``--device name`` (``fit``, ``eval``, ``predict``, ``claims``): ``auto`` is CUDA
    (this rank's local GPU) when available, else CPU (:func:`auto_device`). ``ValueError`` naming the option when
    ``name`` is none of auto, cpu, cuda, cuda:N or asks for a GPU this machine lacks."""
    dist = dist or DistInfo()
    check_device_name(name)
    if name == "auto":
        name = auto_device()
    if name == "cuda":
        name = f"cuda:{dist.local_rank}"
    device = torch.device(name)
    if device.type == "cuda":  # available: check_device_name
        count = torch.cuda.device_count()
        if device.index is not None and device.index >= count:
            raise ValueError(
                f"rank {dist.rank} (local rank {dist.local_rank}) needs {name}, but this machine has "
                f"{count} GPU{'s' * (count != 1)}: start at most {count} process{'es' * (count != 1)} "
                f"per machine (torchrun --nproc_per_node {count}) or train on the CPU (--device cpu)")
        torch.cuda.set_device(device)
    return device


def resolve_amp(cfg: RunConfig, device: torch.device) -> torch.dtype | None:
    """The autocast dtype: ``auto`` is bf16 on CUDA GPUs that support it, else fp16 on CUDA,
    and off (fp32) on the CPU."""
    if cfg.amp == "off" or (cfg.amp == "auto" and device.type != "cuda"):
        return None
    if cfg.amp == "bf16" or (cfg.amp == "auto" and torch.cuda.is_bf16_supported()):
        return torch.bfloat16
    return torch.float16


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed % 2 ** 32)
    torch.manual_seed(seed)



def channels_last_on(cfg: RunConfig, device: torch.device) -> bool:
    """``channels_last``: ``on``, or ``auto`` on CUDA."""
    return cfg.channels_last == "on" or (cfg.channels_last == "auto" and device.type == "cuda")


def same_in_effect(cfg: RunConfig, key: str, value: str, device_name: str) -> bool:
    """Whether ``--amp`` or ``--channels-last`` ``value`` does on device ``device_name`` what run
    ``cfg``'s own setting does (``auto`` is off on the CPU: ``--resume --amp off`` asks there for
    the run's own precision); False for any other option."""
    if key not in ("amp", "channels_last"):
        return False
    try:
        device = torch.device(auto_device() if device_name == "auto" else device_name)
    except (ValueError, RuntimeError):
        return False  # the device is refused later, with its own message
    effect = resolve_amp if key == "amp" else channels_last_on
    return effect(cfg, device) == effect(dataclasses.replace(cfg, **{key: value}), device)


def all_min(t: torch.Tensor, info: DistInfo) -> torch.Tensor:
    """The minimum of ``t`` over the ranks (in place)."""
    if info.world_size > 1:
        import torch.distributed as dist

        dist.all_reduce(t, op=dist.ReduceOp.MIN)
    return t


def all_mean(t: torch.Tensor, info: DistInfo) -> torch.Tensor:
    """The mean of ``t`` over the ranks."""
    if info.world_size > 1:
        import torch.distributed as dist

        dist.all_reduce(t)
        t = t / info.world_size
    return t


def mean_scalars(losses: dict, info: DistInfo) -> dict:
    """The scalar losses of ``losses`` as floats, averaged over the ranks (one collective)."""
    scalars = {k: v.detach().float() for k, v in losses.items() if torch.is_tensor(v) and v.ndim == 0}
    return dict(zip(scalars, all_mean(torch.stack(list(scalars.values())), info).tolist()))


def all_gather(obj, info: DistInfo) -> list:
    """``[obj of rank 0, obj of rank 1, ...]`` (picklable objects)."""
    if info.world_size == 1:
        return [obj]
    import torch.distributed as dist

    out = [None] * info.world_size
    dist.all_gather_object(out, obj)
    return out


class RanksDiverged(RuntimeError):
    """Under DDP a rank's weights differ from rank 0's: a gradient was not averaged (a bug, so
    it keeps its traceback)."""


def check_same_weights(model: torch.nn.Module, info: DistInfo, step: int) -> None:
    """Raise :class:`RanksDiverged` on every rank when some rank's parameters differ from rank
    0's after ``step`` steps (no-op on one process). DDP all-reduces every gradient, so each
    rank takes the same Adam step from the same weights and the parameters stay equal: a
    parameter whose gradient skipped the all-reduce (e.g. from a forward pass outside the DDP
    wrapper that DDP did not see) differs after one step. Compared per parameter tensor: the
    float64 sum and sum of squares (2 numbers per tensor gathered, not the weights), equal up to
    a relative 1e-10 (summation order; one Adam step without the all-reduce moves an element by
    about the learning rate). Buffers (BatchNorm running statistics) are not compared: each rank
    updates them from its own images, and DDP sends rank 0's at every forward."""
    if info.world_size == 1:
        return
    names = [n for n, _ in model.named_parameters()]
    stats = torch.stack([torch.stack([p.detach().double().sum(), p.detach().double().square().sum()])
                         for p in model.parameters()]).cpu()
    gathered = torch.stack(all_gather(stats, info))  # [ranks, tensors, 2]
    differs = ~torch.isclose(gathered, gathered[0], rtol=1e-10, atol=1e-12).all(-1)  # [ranks, tensors]
    ranks = differs.any(1).nonzero().flatten().tolist()
    if ranks:
        bad = [names[i] for i in differs.any(0).nonzero().flatten().tolist()]
        raise RanksDiverged(f"after step {step} rank(s) {ranks} hold weights that differ from rank 0's in "
                            f"{len(bad)} of {len(names)} parameter tensors (first: {bad[0]}): a gradient "
                            f"was not averaged across ranks")
