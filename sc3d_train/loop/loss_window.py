"""The finiteness check of ``fit`` without a host sync per step: each step's total loss is
written into a small device buffer (a copy kernel, no read-back), and the buffer is read once
per check (every ``log_every`` steps, before every checkpoint and at the end), where the first
non-finite step of the window is found exactly."""
from __future__ import annotations

import torch

from sc3d_train.loop.runtime import DistInfo, all_min
from sc3d_train.loop.schedule import phase_at
from sc3d_train.settings.config import RunConfig


class TrainingDiverged(RuntimeError):
    """The loss became NaN/inf; the message names the step and the last good checkpoint."""


class LossWindow:
    """The total losses ``[size]`` (float32) of the steps since the last :meth:`check`, on
    ``device``; ``size`` must be at least the number of steps between two checks (``fit``: the
    least of ``log_every``, ``checkpoint_every`` and the steps left, so that a huge
    ``--log-every`` allocates nothing more)."""

    def __init__(self, size: int, device: torch.device):
        self.totals = torch.zeros(size, dtype=torch.float32, device=device)
        self.first_step: int | None = None  # the step held in slot 0
        self.count = 0

    def record(self, step: int, total: torch.Tensor) -> None:
        """Keep the total loss (a 0-dim tensor on the device) of optimiser step ``step``."""
        if self.first_step is None:
            self.first_step = step
        if self.count >= self.totals.numel():
            raise RuntimeError(f"loss window of {self.totals.numel()} steps is full: check it more often")
        self.totals[self.count] = total.detach()
        self.count += 1

    def check(self, dist: DistInfo) -> tuple[int, float] | None:
        """``(step, loss)`` of the first step of the window whose loss was not finite on some
        rank (the loss is this rank's), or None; empties the window. One read-back (and one
        all-reduce over the ranks)."""
        if self.count == 0:
            return None
        values = self.totals[:self.count]
        finite = all_min(torch.isfinite(values).float(), dist).cpu()
        first = self.first_step
        self.first_step, self.count = None, 0
        bad = (finite < 1).nonzero()
        if not len(bad):
            return None
        i = int(bad[0, 0])
        return first + i, float(values[i])


def check_finite(window: LossWindow, dist: DistInfo, cfg: RunConfig, last_good: str | None) -> None:
    """:class:`TrainingDiverged` naming the first step of ``window`` whose loss was not finite
    (on any rank of ``dist``), its phase in run ``cfg``, and the last good checkpoint (every
    checkpoint is written after a check)."""
    bad = window.check(dist)
    if bad is not None:
        step, value = bad
        raise TrainingDiverged(
            f"loss is {value} at step {step} (phase {phase_at(cfg, step)}); "
            f"last good checkpoint: {last_good or 'none (no checkpoint written yet)'}")
