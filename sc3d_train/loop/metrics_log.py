"""The training log of a run: ``metrics.csv`` (one row per logged step), TensorBoard scalars
(``tb/``) and the ``curves.png`` plot; and two of the measures it logs: the time the loop waits
for data (:class:`DataWaitClock`) and the GPU's utilisation (:class:`GpuUtilisation`)."""
from __future__ import annotations

import csv
import io
import math
import statistics
import time
from pathlib import Path

from sc3d_data.io.pictures import write_figure

CSV_NAME = "metrics.csv"
#: seconds between two drawings of ``curves.png`` at checkpoints (:meth:`MetricsLog.draw_curves`):
#: on an H100 a checkpoint comes every ~8 s and a drawing costs ~0.3-1 s of the loop's host time
CURVES_EVERY_S = 60.0


def complete_rows(path: Path) -> list[dict]:
    """The rows of the CSV log ``path`` (``metrics.csv``, ``validation.csv``) read back on resume,
    less a last row that a crash cut short mid-write (no line end; or a missing column, or a
    step that is no integer), which would otherwise be kept as an early step's row."""
    with open(path, newline="") as f:
        text = f.read()
    if not text.endswith("\n"):
        text = text[: text.rfind("\n") + 1]
    return [r for r in csv.DictReader(io.StringIO(text, newline=""))
            if None not in r and None not in r.values() and str(r.get("step")).isdigit()]


def cell_number(row: dict, key: str) -> float:
    """The number in ``row[key]`` of a CSV log, NaN where the cell is empty, missing or no number
    (a hand-edited or damaged file: its curves are drawn without that point, not refused)."""
    try:
        return float(row.get(key))
    except (TypeError, ValueError):
        return math.nan


def write_csv_atomic(path: Path, fields: list[str] | None, rows: list[dict]) -> None:
    """``path`` rewritten whole as CSV (header ``fields``, then ``rows``; empty without fields),
    through a temporary file renamed over it (``io.shards.atomic_write_bytes``): a kill while a
    resumed run drops its later rows, or a semi run widens the header, leaves the old file, never
    a truncated one that would lose the rows already logged."""
    from sc3d_data.io.shards import atomic_write_bytes

    text = io.StringIO(newline="")
    if fields is not None:
        w = csv.DictWriter(text, fieldnames=fields)
        w.writeheader()
        w.writerows(rows)
    atomic_write_bytes(path, text.getvalue().encode())


def drop_event_files(tb_dir: Path) -> None:
    """Remove the TensorBoard event files in ``tb_dir`` before a new run writes there: they are
    a run's that stopped before its first checkpoint (``fit`` refuses a folder holding anything
    else), which the new run replaces as it replaces ``metrics.csv``. Left, TensorBoard shows both
    runs' values at every step the stopped one logged (a resume purges from its step instead)."""
    for f in Path(tb_dir).glob("events.out.tfevents.*"):
        f.unlink(missing_ok=True)


#: seconds between TensorBoard's writes to disk (its default, 120, is also the longest its writer
#: thread sleeps): a Ctrl-C inside its queue's ``Condition.notify`` (CPython 3.11) leaves a stale
#: waiter that takes the next notify, so closing the writer after that Ctrl-C waited for the thread's
#: sleep to end: ``fit`` stopped up to 2 minutes after its "interrupted" line (3 of 96 Ctrl-C'd runs
#: with the CPU contended; py-spy: ``SummaryWriter.close`` joining a thread asleep in ``Queue.get``)
TB_FLUSH_S = 5


class MetricsLog:
    """Scalars to ``metrics.csv`` (one row per logged step) and TensorBoard (``tb/``).
    On resume, rows at or after the resume step (written after the checkpoint by the
    interrupted run) and a row cut short (:func:`complete_rows`) are dropped first, so the CSV
    has each step once."""

    def __init__(self, run_dir: Path, start_step: int, enabled: bool = True):
        self.path = Path(run_dir) / CSV_NAME
        self.enabled = enabled
        self._drawn_at = -math.inf  # time.monotonic() of the last draw_curves drawing
        self.rows: list[dict] = []
        if not enabled:
            return
        if start_step > 0 and self.path.is_file():
            self.rows = [r for r in complete_rows(self.path) if int(r["step"]) < start_step]
        self.fields = list(self.rows[0].keys()) if self.rows else None
        if self.fields is not None:
            for r in self.rows[1:]:
                self.fields += [k for k in r if k not in self.fields]
        self._rewrite()
        from torch.utils.tensorboard import SummaryWriter

        if start_step == 0:
            drop_event_files(Path(run_dir) / "tb")
        self.tb = SummaryWriter(str(Path(run_dir) / "tb"), purge_step=start_step or None, flush_secs=TB_FLUSH_S)

    def _rewrite(self):
        write_csv_atomic(self.path, self.fields, self.rows)

    def log(self, step: int, values: dict) -> None:
        if not self.enabled:
            return
        row = {"step": step, **values}
        self.rows.append(row)
        new = [k for k in row if k not in (self.fields or [])]
        if new:  # first row, or a phase that logs more terms: widen the header, rewrite the file
            self.fields = (self.fields or []) + new
            self._rewrite()
        else:
            with open(self.path, "a", newline="") as f:
                csv.DictWriter(f, fieldnames=self.fields, extrasaction="ignore").writerow(row)
        for k, v in values.items():
            if isinstance(v, (int, float)):
                self.tb.add_scalar(k if "/" in k else f"train/{k}", v, step)

    def draw_curves(self, png_path: Path, final: bool = False) -> bool:
        """:func:`plot_curves` of this log into ``png_path`` when ``final`` (the run's last
        checkpoint) or when none was drawn in the last :data:`CURVES_EVERY_S` seconds; returns
        whether it drew."""
        now = time.monotonic()
        if not self.enabled or not (final or now - self._drawn_at >= CURVES_EVERY_S):
            return False
        plot_curves(self.path, png_path)
        self._drawn_at = now
        return True

    def close(self):
        if self.enabled:
            self.tb.close()


def in_loop_rate(rates: list[float]) -> float:
    """The run's samples/s in the loop: the median of its logging intervals' rates, the first
    left out where there are more (it holds compiling and the first batches); 0 without any."""
    if not rates:
        return 0.0
    return float(statistics.median(rates[1:] if len(rates) > 1 else rates))


class DataWaitClock:
    """Wall-clock ``seconds`` the training loop spent blocked in ``next`` on the batch
    iterators it wrapped (:meth:`wrap`): the ``data_wait`` share logged by ``fit``."""

    def __init__(self):
        self.seconds = 0.0

    def wrap(self, batches):
        """``batches``, each ``next`` timed into :attr:`seconds`."""
        while True:
            t0 = time.perf_counter()
            try:
                batch = next(batches)
            except StopIteration:
                return
            finally:
                self.seconds += time.perf_counter() - t0
            yield batch


class GpuUtilisation:
    """``probe()``: the device's utilisation (0-1) over the driver's last sample period (NVML via
    ``torch.cuda.utilization``, or ``read``), read at most once every ``every_s`` seconds and the
    last reading in between; None off CUDA or without NVML. Each ``torch.cuda.utilization`` call
    initialises NVML again, NVML samples every 1/6 to 1 s, and ``fit`` logs every 10 steps,
    ~15 times a second on an H100: reading it at every log would cost the loop and tell nothing new."""

    def __init__(self, device, every_s: float = 5.0, read=None, clock=time.monotonic):
        self.device, self.every_s, self.clock = device, every_s, clock
        self.read = read if read is not None else self._nvml
        self.last: float | None = None
        self.read_at = -math.inf

    def _nvml(self) -> float:
        import torch

        return torch.cuda.utilization(self.device) / 100.0

    def __call__(self) -> float | None:
        if self.device.type != "cuda":
            return None
        now = self.clock()
        if now - self.read_at >= self.every_s:
            self.read_at = now
            try:
                self.last = self.read()
            except Exception:  # noqa: BLE001 - pynvml missing or the driver does not report it
                self.last = None
        return self.last


def plot_curves(csv_path: Path, png_path: Path) -> None:
    """Loss terms (log scale) and samples/s against the step, from ``metrics.csv``; with a
    ``validation.csv`` beside it (:mod:`sc3d_train.loop.validation`), a third panel: validation IoU@0.4
    and share within 30 degrees against the step, the best checkpoint's step marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = complete_rows(csv_path)  # rows whose step is a number; their other cells: cell_number
    if not rows:
        return
    val_path = Path(csv_path).with_name("validation.csv")
    val = complete_rows(val_path) if val_path.is_file() else []
    steps = [int(r["step"]) for r in rows]
    # a line through one point draws nothing: a run that logged once (or was resumed at its last
    # logged step) got empty panels; a marker shows its point
    marker = "o" if len(steps) == 1 else None
    fig, axes = plt.subplots(1, 3 if val else 2, figsize=(16 if val else 11, 4))
    ax, ax2 = axes[0], axes[1]
    for key in ("total", "l3d", "l2d", "lsc", "kl", "pose", "u_lsc", "u_pose"):
        if any(r.get(key) not in ("", None) for r in rows):
            vals = [cell_number(r, key) for r in rows]
            if any(v > 0 for v in vals if not math.isnan(v)):
                ax.plot(steps, vals, label=key, marker=marker)
    ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_title("training losses")
    ax.legend(fontsize=8)
    ax2.plot(steps, [cell_number(r, "samples_per_s") for r in rows], marker=marker)
    ax2.set_xlabel("step")
    ax2.set_title("samples/s")
    if val:
        ax3, vsteps = axes[2], [int(r["step"]) for r in val]
        for key, label in (("val_iou", "IoU@0.4"), ("val_rot_acc30", "rotation within 30 deg")):
            ax3.plot(vsteps, [cell_number(r, key) for r in val], marker="o", label=label)
        best = [int(r["step"]) for r in val if r["best"] == "1"]
        if best:
            ax3.axvline(best[-1], color="gray", linestyle=":", label=f"best.pt (step {best[-1]})")
        ax3.set_ylim(0, 1)
        ax3.set_xlabel("step")
        ax3.set_title("validation (objects never trained on)")
        ax3.legend(fontsize=8)
    # the same 0.8 inch for the loss axis' labels ("6x10^-1") whether the figure is 16 or 11 inches wide:
    # 5% of the two-panel figure (a run without validation) cut them at the picture's edge
    fig.subplots_adjust(left=0.8 / fig.get_figwidth(), right=0.99, bottom=0.14, top=0.91, wspace=0.18)
    write_figure(fig, png_path, dpi=80)
    plt.close(fig)
