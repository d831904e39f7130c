"""The one writer of a dataset folder's shards and ``index.json``: what ``render``,
``import-r2n2`` and ``voxelize SHARDS`` share.

A job that writes shards hands its per-object results over in plan order and gets:

- :func:`locked_output`: the folder's write lock (``sc3d_data.io.outlock``) for the whole
  run, so a second writer is refused with one line; no stale ``*.tmp`` before or after.
  ``--overwrite`` removes the files the old index lists (``resume.remove_listed_outputs``)
  when the run starts, after every check (``NewShards``).
- :class:`ShardIndex`: the index of the run as it stands (``io.shards.write_index``'s fields)
  and its atomic writes.
- :func:`write_chunks`: the chunk loop. The executor's results come grouped by chunk, in
  chunk order (``executor.finished_chunks``: chunk ``c`` = plan positions ``c*K .. c*K+K-1``);
  the job's ``store`` writes each chunk's shard and records it in the index, which is then
  written; an I/O error becomes one ``ShardError`` line naming the file.
- :class:`NewShards`: the ``store`` of a job that writes new shards (render, import-r2n2) and
  its resume: chunk ``c`` becomes ``shard-{c:05d}.h5`` (failed objects left out, recorded in
  ``failures`` with the reason); a rerun with the same settings and ``--part`` keeps the chunks
  whose shard is intact (``resume.resume_state``) and does the rest (and, with ``retry_failed``,
  the recorded failures, rewriting their shard in plan order). ``voxelize SHARDS`` stores its
  chunks itself (it rewrites the ``voxels`` of existing shards: ``voxel_job.py``).

Decisions:

- Index writes. Each write rewrites the whole JSON (ShapeNet's 51,000 objects: 14 MB, 1.2 s
  measured on a loaded 2-core machine), so writing after every chunk costs time that grows with the square of the objects.
  The index is rewritten after every chunk while it lists up to :data:`LAZY_OBJECTS` objects;
  beyond, after a chunk only once :data:`LAZY_FACTOR` times the last write's duration has
  passed since it, so writing stays about 1/20 of the run. The last chunk's write, and a write
  put off when the run stops on an error or Ctrl-C, are always made; a kill (SIGKILL) of a
  large run may lose the listing of its last seconds' shards, which a rerun writes again (they
  are this run's own: see below). ``voxelize`` writes after every shard (``lazy=False``): the
  index must never describe the old bytes of a rewritten shard.
- A rerun refuses (``ValueError``, before any work) an index whose objects sit in other chunks
  than this run's plan puts them (the collection changed, or another sc3d made them): resuming
  it would mix two plans in one dataset. It names the gone and new meshes (``run.plan_changes``).
- A file named like a shard this run writes that the index does not list is replaced only if
  it is a shard made with this run's settings (left by a run killed before its index listed
  it); anything else stops the run before any work, naming the file.
"""
from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

from sc3d_data.io.shards import (SHARD_PATTERN, ShardError, add_shard_to_index, index_path, io_reason, load_index,
                                 shard_path, voxels_attr)
from sc3d_data.io.shards import write_index as write_index_file
from sc3d_data.pipeline.executors.executor import Executor, finished_chunks
from sc3d_data.pipeline.run.plan_changes import plan_change_text, plan_changes
from sc3d_data.pipeline.run.resume import (check_resume, empty_state, listed_shard_names, remaining, remove_listed_outputs,
                                           resume_state)
from sc3d_data.pipeline.run.resume_voxels import voxels_after_rewrite

#: an index listing more objects than this is written lazily (module doc)
LAZY_OBJECTS = 10_000
#: a lazy write comes after this many times the last write's duration
LAZY_FACTOR = 20
#: the keys of ``index.json`` that :class:`ShardIndex` derives or holds; the others are ``extra``
_INDEX_KEYS = ("schema_version", "sc3d_version", "complete", "settings", "split", "counts", "clipped", "shards",
               "empty_chunks", "objects", "failures", "skipped", "warnings")


@contextmanager
def locked_output(out: Path, command: str, create: bool = True) -> Iterator[Path]:
    """Hold ``out``'s write lock for the ``with`` block (``LockError`` naming the folder and the
    PID that holds it); ``create``: make the folder first (``ValueError`` when ``out`` is a file
    or cannot be made; a folder made here that the run leaves empty is removed, with the parents
    made for it). Stale ``*.tmp`` files of a killed run are deleted at the start and
    whatever this run leaves at the end. (``--overwrite`` deletes the old outputs only when the
    run starts, after every check: ``NewShards.resume``.)"""
    from sc3d_data.io.outlock import exclusive_lock, missing_folders
    from sc3d_data.pipeline.run.resume import check_out, tmp_cleaned

    out = Path(out)
    made = missing_folders(out) if create else []  # removed again when the run leaves nothing in them
    if create:
        check_out(out)
    with exclusive_lock(out, command, made=made, advice="wait for it to finish" + " or use another --out" * create):
        with tmp_cleaned(out):
            yield out


@dataclass
class ShardIndex:
    """``index.json`` of ``out`` while a run writes it: the lists ``io.shards.write_index``
    takes (entries as SPEC, "Index"), ``problems`` (failures without a plan position, listed
    before ``failures``), ``extra`` top-level keys (``part``, ``merged``, ``voxels``) and
    ``complete``. ``lazy``: writes after a chunk may wait when the index is large (module doc)."""

    out: Path
    settings: dict
    split: dict
    extra: dict = field(default_factory=dict)
    problems: list[dict] = field(default_factory=list)
    skipped: list[dict] = field(default_factory=list)
    shards: list[dict] = field(default_factory=list)
    objects: list[dict] = field(default_factory=list)
    failures: list[dict] = field(default_factory=list)
    warnings: list[dict] = field(default_factory=list)
    empty_chunks: list[int] = field(default_factory=list)
    complete: bool = False
    lazy: bool = True
    _write_s: float = field(default=0.0, init=False, repr=False)  # how long the last write took
    _written_at: float = field(default=0.0, init=False, repr=False)  # time.monotonic() at its end
    _pending: bool = field(default=False, init=False, repr=False)  # a write was put off

    @classmethod
    def load(cls, out: Path, lazy: bool = True) -> "ShardIndex":
        """The index ``out`` holds, to be changed and written back (``voxelize``): its keys
        come back in their order, with ``counts`` and ``clipped`` derived again."""
        index = load_index(out)
        return cls(Path(out), index.get("settings", {}), index.get("split", {}),
                   extra={k: v for k, v in index.items() if k not in _INDEX_KEYS},
                   **{k: list(index.get(k, [])) for k in ("skipped", "shards", "objects", "failures", "warnings",
                                                          "empty_chunks")},
                   complete=bool(index.get("complete")), lazy=lazy)

    def write(self, final: bool = True) -> None:
        """Write ``index.json`` atomically as it stands. ``final=False`` (after a chunk that is
        not the run's last) may put the write off when the index is large (module doc)."""
        start = time.monotonic()
        if (not final and self.lazy and len(self.objects) > LAZY_OBJECTS
                and start - self._written_at < LAZY_FACTOR * self._write_s):
            self._pending = True
            return
        write_index_file(self.out, complete=self.complete, settings=self.settings, split=self.split,
                         shards=self.shards, objects=self.objects, failures=self.problems + self.failures,
                         skipped=self.skipped, warnings=self.warnings, empty_chunks=self.empty_chunks,
                         extra=self.extra)
        self._written_at = time.monotonic()
        self._write_s, self._pending = self._written_at - start, False

    def flush(self) -> None:
        """Make a write that was put off, if any."""
        if self._pending:
            self.write()


def write_chunks(index: ShardIndex, pool: Executor | None, todo: list, chunk_size: int, n_workers: int,
                 store: Callable[[int, list, bool], None], progress: Callable[[int], None] | None = None) -> None:
    """The chunk loop: write ``index``, run ``todo`` (tasks in plan order, ``pos`` their plan
    position) on ``pool`` and, per chunk ``pos // chunk_size`` in chunk order, call
    ``store(chunk, [(task, status, payload), ...], last)`` (it writes the chunk's shard and
    updates ``index``), then write ``index``. ``progress(1)`` per result. A write put off is
    made when the loop stops early (error, Ctrl-C); an ``OSError`` (disk full...) is raised as
    ``ShardError`` naming the file."""
    try:
        try:
            index.write()
            if pool is not None and todo:
                for c, results, last in finished_chunks(pool, todo, chunk_size, n_workers, progress):
                    store(c, results, last)
                    index.write(final=last)
        except BaseException:
            try:
                index.flush()
            except OSError:
                pass  # the error being raised says more
            raise
    except OSError as e:
        raise ShardError(f"{e.filename or index_path(index.out)}: {io_reason(e)}") from e


@dataclass
class NewShards:
    """A run that writes new shards into ``index`` (render, import-r2n2): this run's plan
    ``tasks`` (positions 0..), what it still has to do (``todo``), how many objects it kept
    (``resumed``), the plan positions it retries, the kept shards found broken (``repaired``:
    one line each; their chunks are done again) and, after :meth:`run`, the objects it wrote
    (``done``) and its ``new_failures``. ``attempts`` (plan position -> attempts so far; None:
    failures carry no count), ``old_settings`` and ``old_files`` (the resumed index's settings
    and shard file names, intact or not) and ``pos_of`` (each task's plan position by
    ``(category, model_id)``) come from the resume."""

    index: ShardIndex
    tasks: list
    chunk_size: int
    todo: list = field(default_factory=list)
    resumed: int = 0
    retry: set = field(default_factory=set)
    repaired: list[str] = field(default_factory=list)
    attempts: dict | None = None
    old_settings: dict = field(default_factory=dict)
    old_files: set[str] = field(default_factory=set)
    pos_of: dict = field(default_factory=dict)  # (category, model_id) -> plan position of tasks
    done: int = 0
    new_failures: list[dict] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # lines for the user (``resume_voxels.voxels_after_rewrite``)
    unlisted: set = field(default_factory=set)  # of ``retry``: kept chunks' objects the index did not list
    replace_old: bool = False  # --overwrite: the old outputs are deleted when ``run`` starts

    @classmethod
    def resume(cls, index: ShardIndex, tasks: list, chunk_size: int, defaults: dict | None = None,
               retry_failed: bool = False, count_attempts: bool = False, overwrite: bool = False) -> "NewShards":
        """The run over ``tasks`` in chunks of ``chunk_size`` that ``index.out`` lets this run
        make: fresh (``overwrite``: its old outputs deleted when :meth:`run` starts, so a refused
        run deletes nothing), or what its index keeps (module doc). ``defaults``: the values of
        settings an older index lacks; ``count_attempts``: failures record their ``attempts``.
        ``ValueError``: other settings or ``--part``, another plan, a foreign shard-named file."""
        out, K = index.out, chunk_size
        old, state, listed = None, empty_state(), set()
        if index_path(out).is_file() and overwrite:
            listed = listed_shard_names(out)
        elif index_path(out).is_file():
            old = load_index(out, listing=False)
            check_resume(out, old, index.settings, defaults or {}, index.extra["part"])
            state = resume_state(out, old, retry_failed, K, tasks, index.settings.get("meshes"))
            listed = {s["file"] for s in old.get("shards", [])}
        pos_of = {(t.category, t.model_id): t.pos for t in tasks}
        if any(pos_of.get((o["category"], o["model_id"]), -K) // K != o["chunk"] for o in state["objects"]):
            raise ValueError(plan_change_text(out, *plan_changes(old, tasks, K), old.get("skipped", [])))
        for key in ("shards", "objects", "warnings", "empty_chunks"):
            setattr(index, key, state[key])
        index.failures = sorted(state["failures"], key=lambda f: f.get("pos", -1))
        index.extra.update(state["extra"])
        todo, resumed = remaining(tasks, state, K)
        run = cls(index, tasks, K, todo, resumed, state["retry"], state["broken"],
                  state["attempts"] if count_attempts else None, (old or {}).get("settings", {}), listed, pos_of)
        run.unlisted = state["unlisted"]
        run.replace_old = overwrite and index_path(out).is_file()
        run.check_unlisted()
        return run

    def check_unlisted(self) -> None:
        """``ValueError`` naming a file named like a shard this run writes that the index did
        not list (intact or not) and that is not a shard of this run's settings (module doc)."""
        from sc3d_data.pipeline.run.resume import check_unlisted_shard

        for c in sorted({t.pos // self.chunk_size for t in self.todo}):
            path = self.index.out / SHARD_PATTERN.format(c)
            if path.name not in self.old_files:
                check_unlisted_shard(path, self.index.settings, index_path(self.index.out), "this run",
                                     "move it away or use another --out")

    def run(self, pool: Executor | None, n_workers: int, progress: Callable[[int], None] | None = None,
            bar: str | None = None) -> None:
        """Do ``todo`` on ``pool`` (``write_chunks``); ``progress(1)`` per object, or with
        ``bar`` (its description) a progress bar on stderr."""
        if self.replace_old:  # --overwrite: every check has passed
            remove_listed_outputs(self.index.out)
            self.replace_old = False
        self.index.complete = not self.todo
        shown = None
        if bar and progress is None and self.todo:
            from sc3d_data.pipeline.run.progress import progress_bar

            shown = progress_bar(total=len(self.todo), unit="obj", desc=bar)
            progress = shown.update
        try:
            write_chunks(self.index, pool, self.todo, self.chunk_size, n_workers,
                         lambda c, results, last: self.store(pool, c, results, last), progress)
        finally:
            if shown is not None:
                shown.close()

    def store(self, pool: Executor, c: int, results: list, last: bool) -> None:
        """Chunk ``c``'s results ``[(task, status, payload)]`` (payload ``(ObjectRecord, warnings)`` or the reason)
        into its shard, written by ``pool``, and the index; a chunk whose re-tried objects all failed again keeps it."""
        from sc3d_data.io.shard_reader import read_records

        index = self.index
        index.complete = last
        records = []
        for t, status, payload in results:
            if status == "ok":
                record, warns = payload
                records.append((t.pos, record))
                index.warnings.extend({"source": t.path, "warning": w, "chunk": c} for w in warns)
            else:
                failure = {"source": t.path, "category": t.category, "model_id": t.model_id, "reason": payload,
                           "chunk": c, "pos": t.pos}
                if self.attempts is not None:
                    failure["attempts"] = self.attempts.get(t.pos, 0) + 1
                self.new_failures.append(failure)
                index.failures.append(failure)
        index.failures.sort(key=lambda f: f.get("pos", -1))
        self.done += len(records)
        kept = [sh for sh in index.shards if sh["chunk"] == c]
        if kept and not records:
            return
        if kept:  # a re-tried chunk: its shard's objects plus the new ones, in plan order (a new one replaces its row)
            redone = {pos for pos, _ in records}
            records += [(pos, r) for r in read_records(shard_path(index.out, kept[0]["file"]))
                        if (pos := self.pos_of[(r.category, r.model_id)]) not in redone]
            index.shards.remove(kept[0])
            index.objects[:] = [o for o in index.objects if o.get("chunk") != c]
        if c in index.empty_chunks:
            index.empty_chunks.remove(c)
        records = [r for _, r in sorted(records, key=lambda pr: pr[0])]
        index.failures = voxels_after_rewrite(index, SHARD_PATTERN.format(c), records, self.notes)
        if records:  # the grids voxelize SHARDS gave the dataset, where the shard keeps them: named in its attributes
            name, made = SHARD_PATTERN.format(c), index.extra.get("voxels")
            add_shard_to_index(index.shards, index.objects, name, c, records,
                               sha256=pool.write_shard(index.out / name, records, index.settings, made and voxels_attr(made)))
        else:
            index.empty_chunks.append(c)
