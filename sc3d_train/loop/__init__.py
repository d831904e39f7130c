"""``fit`` and the state of a run: the trainer, its schedule, loader streams, the step (eager or
compiled), runtime (ranks, device, AMP, seeds), metrics, checkpoints, validation and the run's
resolved config (``resolve``: it reads the shards and the run folder, so it sits here rather than
in ``settings``). Imports ``settings``, ``paper`` and ``data``."""
