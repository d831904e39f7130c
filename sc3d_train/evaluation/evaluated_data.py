"""What an evaluation measured, as one digest: ``eval`` records it in ``metrics.json``
(``data_sha256``) and ``claims`` reuses an evaluation only while its shards still give the same
digest (shards re-rendered in place with other settings, objects or a new split are evaluated
again)."""
from __future__ import annotations

import hashlib
import json
from pathlib import Path


def evaluated_data_digest(shards: Path, split: str, objects) -> str:
    """SHA-256 (hex) of what evaluating ``split`` of ``shards`` reads: the sorted
    ``category/model_id`` of ``objects`` (the ``ObjectRef``s evaluated), the render ``settings``
    of ``shards/index.json`` and the ``sha256`` of each of its shard files in index order (None
    where the index records none). Reads ``index.json`` only; ``DataError`` when it cannot be
    read."""
    from sc3d_data.io.shards import ShardError, load_index
    from sc3d_train.data.dataset import DataError

    try:
        index = load_index(Path(shards))
    except (ShardError, OSError) as e:
        raise DataError(str(e)) from e
    content = {"split": split, "objects": sorted(f"{r.category}/{r.model_id}" for r in objects),
               "settings": index.get("settings", {}),
               "shard_sha256": [entry.get("sha256") for entry in index.get("shards", [])]}
    return hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()


def split_digest(shards: Path, split: str) -> str:
    """:func:`evaluated_data_digest` of every object of ``split`` of ``shards`` (what ``eval``
    evaluates: ``ShardDataset(shards, split)``'s objects)."""
    from sc3d_train.data.dataset import scan_objects

    refs, _ = scan_objects(Path(shards))
    return evaluated_data_digest(shards, split, [r for r in refs if r.split == split])
