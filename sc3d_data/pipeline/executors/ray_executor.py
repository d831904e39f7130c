"""Ray executor of ``render``, ``voxelize --meshes`` and ``import-r2n2`` with ``--executor ray
[--address auto|HOST:PORT]``.

Each object is one Ray task running the job's ``run`` (``executor.Job``: for rendering
:func:`render_job.render_task`, 1 CPU). Ray worker processes are reused between tasks, and
each keeps its per-worker state (one renderer, ``Job.start``), so the per-object cost is the
same as in the local pool plus Ray's scheduling. A task has two results: the object's index
fields and status (small, fetched by the driver) and its arrays (left in the object store;
a job whose result is not an ``ObjectRecord``, e.g. the path of a ``.binvox`` file the
worker wrote, returns it as the first result and nothing as the second). When a chunk is complete the driver asks a Ray task to write its
shard (``write_shard``): that task receives the arrays straight from the object store and
writes the file into ``--out``, which must therefore be one shared folder, at the same path,
for the driver and every node (on one machine: any folder). The arrays never pass through
the driver; it writes ``index.json``.

- Cluster: ``address=None`` starts a local Ray cluster with ``n_workers`` CPUs for the run and
  stops it at the end; ``"auto"`` or ``HOST:PORT`` joins a running one (sc3d must be
  installed on its nodes, ``--meshes`` readable at the same path). A Ray session the caller
  already started (``ray.init``) is used as it is.
- Time limit: the task itself arms a ``SIGALRM`` timer of ``config.timeout_s`` once its
  worker's state exists (so a worker's start-up does not count, as in the local pool); a
  loader that blocks (a FIFO, a stuck network file system) is interrupted and the object is
  recorded as failed with the reason, and the worker drops its state (``Job.drop``). A hang the signal
  cannot interrupt (inside a C call) is caught by the driver: a task still running
  ``2 * timeout_s + 60`` s after its submission is cancelled with ``force=True`` (its worker
  process is killed) and recorded the same way. The run goes on in both cases.
- Retries: a task whose worker process dies (killed, OOM, segfault) is run again by Ray up to
  ``config.retries`` times; after that it is recorded as failed. Errors of the mesh itself are
  results (``"fail"``), never retried.
- Results: same ``(pos, status, payload)`` stream as ``local_pool.WorkerPool.run``.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

from sc3d_data.pipeline.executors.job import CRASH_ENV, THREAD_ENV, Job

MISSING = "the Ray executor needs Ray: pip install 'sc3d[ray]'"


def require_ray():
    """``import ray`` or ``ImportError`` with the one-line install hint."""
    try:
        import ray
    except ImportError:
        raise ImportError(MISSING) from None
    return ray


def worker_env(local: bool) -> dict:
    """``runtime_env`` of sc3d's Ray workers: one BLAS thread each; on a local cluster also this
    checkout on ``PYTHONPATH`` (workers import the same sc3d as the driver)."""
    env = dict(THREAD_ENV)
    if os.environ.get(CRASH_ENV):  # the test-only fault injection reaches the workers
        env[CRASH_ENV] = os.environ[CRASH_ENV]
    if local:
        root = str(Path(__file__).resolve().parents[3])
        env["PYTHONPATH"] = os.pathsep.join([root] + [p for p in [os.environ.get("PYTHONPATH")] if p])
    return {"env_vars": env}


def init_local(num_cpus: int):
    """Start a local Ray cluster of ``num_cpus`` CPUs for sc3d (no dashboard, quiet)."""
    ray = require_ray()
    ray.init(num_cpus=num_cpus, include_dashboard=False, runtime_env=worker_env(True),
             logging_level="warning", log_to_driver=False, configure_logging=True)
    return ray


class _TimedOut(BaseException):
    """Raised by the ``SIGALRM`` handler (a BaseException: ``render_task`` does not catch it)."""


def timed_task(job: Job, config, backend: str, task):
    """``job.run`` under a ``SIGALRM`` timer of ``config.timeout_s`` (module doc)."""
    import signal
    import threading

    job.start(config, backend)  # start-up is not the object's time
    if threading.current_thread() is not threading.main_thread():
        return job.run(config, backend, task)

    def on_alarm(signum, frame):
        raise _TimedOut()

    old = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, config.timeout_s)
    try:
        return job.run(config, backend, task)
    except _TimedOut:
        if job.drop is not None:
            job.drop()  # it may have been interrupted mid-draw
        return task.pos, "fail", f"{task.path}: timed out after {config.timeout_s:g} s (--timeout)"
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


@dataclass
class RecordRef:
    """What the driver holds for a rendered object: its index fields (``clipped`` [V] is the
    only array) and ``ref``, the Ray object holding its ``ObjectRecord``."""

    model_id: str
    category: str
    split: str
    source: str
    arrays: dict
    ref: object = None
    source_file: dict | None = None  # the source file's fingerprint, as the worker took it


def job_task_split(job: Job, config, backend: str, task):
    """:func:`timed_task` as two Ray results: ``(pos, status, payload)`` with the record
    replaced by a :class:`RecordRef` (no ``ref`` yet), and the ``ObjectRecord`` (None on failure
    or when the result is not an ``ObjectRecord``)."""
    from sc3d_data.io.shards import ObjectRecord

    _use_ray_gpu(job, config)
    pos, status, payload = timed_task(job, config, backend, task)
    if status != "ok" or not isinstance(payload[0], ObjectRecord):
        return (pos, status, payload), None
    record, warnings = payload
    stub = RecordRef(record.model_id, record.category, record.split, record.source,
                     {"clipped": record.arrays["clipped"]}, source_file=record.source_file)
    return (pos, status, (stub, warnings)), record


def _write_shard_task(path: str, settings: dict, attrs: dict | None, *records) -> str:
    """``sc3d_data.io.shards.write_shard`` on a worker (Ray hands ``records`` over resolved)."""
    from sc3d_data.io.shards import write_shard

    return write_shard(Path(path), list(records), settings, attrs)


def _probe_backend(job: Job, config) -> str:
    """Make this worker's state (renderer); the GL backend it got."""
    _use_ray_gpu(job, config)
    return job.start(config, config.backend if job.gl else "cpu")


def _gpu_share(job: Job, config, slots: int) -> float:
    """GPUs one task asks Ray for: with ``--gpus``, a share of one GPU such that ``slots`` tasks
    fit on ``len(gpus)`` GPUs (each task draws on one GPU); else none."""
    gpus = tuple(getattr(config, "gpus", ())) if job.gl else ()
    return min(1.0, len(gpus) / slots) if gpus else 0.0


def _use_ray_gpu(job: Job, config) -> None:
    """In a Ray task with ``--gpus``: draw on the GPU Ray assigned to this task (its id taken as
    the EGL device index; the renderer reads it when it makes its context)."""
    import ray

    from sc3d_data.pipeline.executors.devices import DEVICE_ENV

    if job.gl and getattr(config, "gpus", ()) and ray.get_gpu_ids():
        os.environ.setdefault(DEVICE_ENV, str(int(ray.get_gpu_ids()[0])))


class RayExecutor:
    """See module doc; make one with :meth:`start`."""

    def __init__(self, ray, config, backend: str, slots: int, owns_cluster: bool, job: Job):
        self.ray, self.config, self.backend, self.slots, self.job = ray, config, backend, slots, job
        self.owns_cluster = owns_cluster
        self.remote = ray.remote(job_task_split).options(num_cpus=1, num_gpus=_gpu_share(job, config, slots),
                                                            num_returns=2, max_retries=config.retries,
                                                            retry_exceptions=False)
        # compressing a shard runs beside the renders, as the local pool's main process does
        self.writer = ray.remote(_write_shard_task).options(num_cpus=0, max_retries=config.retries)

    @classmethod
    def start(cls, config, n_workers: int, job: Job) -> "RayExecutor":
        """Join or start the cluster (module doc) and set up one worker per CPU slot (one
        renderer each; the first error of the GL backend is raised here, naming the packages)."""
        ray = require_ray()
        owns = False
        if not ray.is_initialized():
            if config.address:
                ray.init(address=config.address, runtime_env=worker_env(False), logging_level="warning",
                         log_to_driver=False)
            else:
                init_local(n_workers)
                owns = True
        slots = int(config.workers or ray.cluster_resources().get("CPU", n_workers))
        slots = max(1, slots)
        if _gpu_share(job, config, slots) and not ray.cluster_resources().get("GPU"):
            if owns:  # its tasks could never be scheduled: the run would wait for ever
                ray.shutdown()
            raise RuntimeError(f"--gpus {','.join(map(str, config.gpus))}: the Ray cluster has no GPU "
                               "(ray.cluster_resources() lists none); run without --gpus, or on GPU nodes")
        probe = ray.remote(_probe_backend).options(num_cpus=1, num_gpus=_gpu_share(job, config, slots),
                                                   max_retries=0)
        try:
            backends = ray.get([probe.remote(job, config) for _ in range(slots)])
        except Exception as e:
            if owns:
                ray.shutdown()
            cause = getattr(e, "cause", None) or e
            raise RuntimeError(f"Ray {job.name} workers could not start: {type(cause).__name__}: {cause}") from None
        return cls(ray, config, backends[0], slots, owns, job)

    def run(self, tasks, may_dispatch=lambda pos: True):
        ray, timeout = self.ray, self.config.timeout_s
        backstop = 2 * timeout + 60
        todo = list(tasks)[::-1]  # pop() from the end = plan order
        inflight: dict = {}  # status ObjectRef -> (task, submitted, record ObjectRef)
        while todo or inflight:
            while todo and len(inflight) < self.slots and may_dispatch(todo[-1].pos):
                task = todo.pop()
                status_ref, record_ref = self.remote.remote(self.job, self.config, self.backend, task)
                inflight[status_ref] = (task, time.monotonic(), record_ref)
            now = time.monotonic()
            wait_s = min([s + backstop - now for _, s, _ in inflight.values()], default=1.0)
            ready, _ = ray.wait(list(inflight), num_returns=1, timeout=max(0.0, min(wait_s, 1.0)))
            for ref in ready:
                task, _, record_ref = inflight.pop(ref)
                try:
                    result = ray.get(ref)
                    if result[1] == "ok" and isinstance(result[2][0], RecordRef):
                        result[2][0].ref = record_ref
                except ray.exceptions.RayError as e:  # the worker died on every attempt
                    why = type(getattr(e, "cause", None) or e).__name__
                    result = (task.pos, "fail", f"{task.path}: {self.job.name} worker died on all "
                                                f"{self.config.retries + 1} attempts ({why}; --retries)")
                yield result
            now = time.monotonic()
            for ref, (task, submitted, _) in list(inflight.items()):
                if now - submitted > backstop:
                    ray.cancel(ref, force=True)  # kills the worker process running it
                    del inflight[ref]
                    yield task.pos, "fail", (f"{task.path}: timed out: still running {backstop:g} s after it was "
                                             f"sent, its --timeout {timeout:g} s timer could not interrupt it")

    def write_shard(self, path: Path, records: list, settings: dict, attrs: dict[str, str] | None = None) -> str:
        """Write the shard on a Ray worker from the objects' arrays in the object store (records
        read back from an existing shard on a retry are sent along); returns its SHA-256.
        ``ShardError`` naming the file when the worker cannot write it."""
        from sc3d_data.io.shards import ShardError

        args = [r.ref if isinstance(r, RecordRef) else r for r in records]
        try:
            return self.ray.get(self.writer.remote(str(path), settings, attrs, *args))
        except self.ray.exceptions.RayTaskError as e:
            cause = getattr(e, "cause", None)
            raise (cause if isinstance(cause, ShardError) else ShardError(f"{path}: cannot write shard on a Ray "
                                                                          f"worker ({type(cause or e).__name__}: "
                                                                          f"{cause or e})")) from None

    def close(self) -> None:
        if self.owns_cluster and self.ray.is_initialized():
            self.ray.shutdown()
