"""Whether a shard folder holds everything its render planned: ``index.json``'s ``complete`` is
false while a render (or ``import-r2n2``) was cut short and not yet rerun (SPEC: a rerun of the
same command resumes and sets it). Training on such a folder trains on part of the data, and once
the render is finished the run cannot be resumed (its objects changed), so ``fit`` and ``claims``
refuse it; ``eval`` says so beside its figures."""
from __future__ import annotations

from pathlib import Path


def shards_complete(shards: Path) -> bool:
    """``index.json``'s ``complete`` (an index without the key, from an earlier sc3d: complete).
    Errors of a missing or unreadable index are left to the readers that follow."""
    from sc3d_data.io.shards import ShardError, load_index

    try:
        return load_index(Path(shards)).get("complete", True) is not False
    except (ShardError, OSError, ValueError):
        return True


def require_complete(shards: Path) -> None:
    """``DataError`` naming ``shards`` when a render left it incomplete."""
    from sc3d_train.data.dataset import DataError

    if not shards_complete(shards):
        raise DataError(f"{shards}: incomplete: index.json says its render was cut short (complete: false); "
                        "finish it with the same render command (it resumes), then train on it")
