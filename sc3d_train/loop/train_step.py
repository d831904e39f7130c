"""One optimiser step of ``fit`` (forward, losses, backward, Adam), eager or compiled.

What is compiled
    The forward passes of the step and its losses (:func:`~sc3d_train.loop.phase_step.step_losses`
    under the run's autocast) go through ``torch.compile`` as one function of the device
    batches; AOTAutograd compiles their backward with them, which ``loss.backward()`` runs.
    Adam stays outside (``fused=True`` on CUDA: a handful of kernels for all weights, and the
    learning rate can change every step without recompiling). The batch's shapes are fixed
    within a phase (the loader drops incomplete batches), so the step is compiled with
    ``dynamic=False``: one graph per phase (the mixed phase of ``semi``: one graph with both
    passes).
When (:func:`compile_plan`)
    ``compile: auto`` compiles on one CUDA device with mode ``reduce-overhead``: inductor's
    kernels replayed as CUDA graphs. At the paper's width the step is bound by kernel launches
    and host work (issue 21: plain fp32 eager 31 ms at batch 48 on an H100), which CUDA graphs
    remove; ``max-autotune`` would tune matrix kernels this small network does not wait on and
    adds minutes of compile time to a 10-minute run. ``auto`` stays eager on the CPU (inductor's
    C++ build of the step takes about 2 minutes on 2 cores, the step is compute bound there) and
    under torchrun (DDP's gradient all-reduce hooks between graphs; not measured). ``on`` forces
    compiling: CUDA graphs on one CUDA device, mode ``default`` elsewhere. ``off``: eager.
Random numbers
    The reparameterisation noise is drawn before the compiled function (:func:`draw_noise`) in
    the order of the eager step, so the compiled and the eager step see the same numbers and a
    run may switch ``compile`` on ``--resume``.
When compiling fails
    The first compiled steps of each kind of batch (the supervised phase's, then the mixed
    phase's, which compiles its own graph when it starts; :data:`PROVEN_AFTER` of each, since
    CUDA graphs are recorded on the second call, not the first) run forward and backward only
    after the model's buffers (BatchNorm statistics) are copied; if one raises (no C++ compiler,
    no triton, an op inductor cannot lower, a graph that cannot be recorded), the buffers are put
    back, one line says why, and the run continues eagerly from the same state. An error that the
    eager step raises too is raised from there.
"""
from __future__ import annotations

from contextlib import nullcontext
from dataclasses import dataclass

import torch

from sc3d_train.settings.config import RunConfig
from sc3d_train.loop.phase_step import backward, optimizer_step, step_losses

#: the order in which the passes of a step draw their noise (the eager step's order)
PASS_ORDER = ("supervised", "unsupervised")


#: compiled steps of one kind of batch that run guarded (module doc): the first compiles, the
#: second records the CUDA graph
PROVEN_AFTER = 2


def batch_kind(batches: dict) -> tuple:
    """What makes the compiled step compile anew (``dynamic=False``): the parts of ``batches``
    (``{part: {name: tensor}}``) with their tensors' names and shapes."""
    return tuple((part, name, tuple(v.shape)) for part, batch in sorted(batches.items())
                 for name, v in sorted(batch.items()))


@dataclass(frozen=True)
class CompilePlan:
    """Whether and how the step is compiled: ``mode`` is torch.compile's (None: default),
    ``why`` one line for the log."""

    enabled: bool
    mode: str | None
    backend: str
    why: str

    @property
    def cuda_graphs(self) -> bool:
        return self.enabled and self.mode == "reduce-overhead"


def compile_plan(cfg: RunConfig, device: torch.device, world_size: int) -> CompilePlan:
    """The plan of ``cfg.compile`` on ``device`` with ``world_size`` ranks (module doc)."""
    if cfg.compile == "off":
        return CompilePlan(False, None, cfg.compile_backend, "compile: off")
    graphs = device.type == "cuda" and world_size == 1 and cfg.compile_backend == "inductor"
    if cfg.compile == "auto" and (device.type != "cuda" or world_size > 1):
        where = "on the CPU" if device.type != "cuda" else "under torchrun"
        return CompilePlan(False, None, cfg.compile_backend, f"compile: auto is eager {where}")
    mode = "reduce-overhead" if graphs else None
    return CompilePlan(True, mode, cfg.compile_backend,
                       f"torch.compile ({cfg.compile_backend}, mode {mode or 'default'})")


def draw_noise(batches: dict, shape_dim: int) -> None:
    """Add ``noise [B, shape_dim]`` (standard normal, float32, the batch's device) to each
    device batch of ``batches``, in :data:`PASS_ORDER`."""
    for phase in PASS_ORDER:
        if phase in batches:
            images = batches[phase]["images"]
            batches[phase]["noise"] = torch.randn(images.shape[0], shape_dim, device=images.device)


class TrainStep:
    """``step(batches) -> losses``: one optimiser step on the phase's device batches
    (``{"supervised": ...}``, ``{"unsupervised": ...}`` or both; the reparameterisation
    ``noise`` is drawn here). The losses are the step's scalar tensors on the device (with
    CUDA graphs: valid until the next step; read or copy them before)."""

    def __init__(self, model: torch.nn.Module, train_model: torch.nn.Module, optimizer: torch.optim.Optimizer,
                 scaler, amp_dtype: torch.dtype | None, cfg: RunConfig, plan: CompilePlan, say=print):
        self.model, self.train_model, self.optimizer, self.scaler = model, train_model, optimizer, scaler
        self.amp_dtype, self.cfg, self.plan, self.say = amp_dtype, cfg, plan, say
        self.device_type = next(model.parameters()).device.type
        self.compiled = None
        if plan.enabled:
            self.compiled = torch.compile(self.losses, mode=plan.mode, backend=plan.backend, dynamic=False)
        self.proven: dict[tuple, int] = {}  # kind of batch -> compiled steps that ran forward and backward

    def losses(self, batches: dict) -> dict:
        """The step's losses (eager; the function that is compiled)."""
        amp = torch.autocast(self.device_type, dtype=self.amp_dtype) if self.amp_dtype else nullcontext()
        with amp:
            return step_losses(batches, self.model, self.train_model, self.cfg.mode, self.cfg.loss_weights,
                               self.model.pose_grid)

    def __call__(self, batches: dict) -> dict:
        batches = {p: {k: v for k, v in b.items() if torch.is_tensor(v)} for p, b in batches.items()}
        draw_noise(batches, self.cfg.model.shape_dim)
        self.train_model.train()
        self.optimizer.zero_grad(set_to_none=True)
        kind = batch_kind(batches) if self.compiled is not None else None  # eager: nothing to guard
        if kind is not None and self.proven.get(kind, 0) < PROVEN_AFTER:
            losses = self._first_compiled(batches, kind)
        else:
            losses = self._forward(batches)
            backward(losses["total"], self.scaler)
        optimizer_step(self.optimizer, self.scaler)
        return losses

    def _forward(self, batches: dict) -> dict:
        if self.compiled is None:
            return self.losses(batches)
        if self.plan.cuda_graphs:  # a new iteration: the previous step's graph outputs may be reused
            torch.compiler.cudagraph_mark_step_begin()
        return self.compiled(batches)

    def _first_compiled(self, batches: dict, kind: tuple) -> dict:
        """Forward and backward through the compiled step; on failure, the buffers restored,
        one line, and the eager step from the same state."""
        buffers = {k: v.detach().clone() for k, v in self.model.named_buffers()}
        try:
            losses = self._forward(batches)
            backward(losses["total"], self.scaler)
        except Exception as e:  # noqa: BLE001 - any failure of compiling: the eager step decides
            first = " ".join(str(e).strip().splitlines()[:1])[:200]
            self.say(f"{self.plan.why} failed ({type(e).__name__}: {first}); training eagerly "
                     f"(--compile off skips this)")
            with torch.no_grad():
                for k, v in self.model.named_buffers():
                    v.copy_(buffers[k])
            self.compiled = None
            self.optimizer.zero_grad(set_to_none=True)
            losses = self.losses(batches)
            backward(losses["total"], self.scaler)
            return losses
        self.proven[kind] = self.proven.get(kind, 0) + 1
        return losses
