"""Which rows of a dataset hold no voxel grid of their object: the placeholders ``sc3d-data
voxelize SHARDS`` leaves where it could not voxelize an object.

Such an object keeps its row, with an empty grid (the shard stays rectangular), and an entry
``"stage": "voxelize"`` in the index's ``failures`` naming its shard and row (SPEC "Shards").
An empty grid is no ground truth and no voxelization to check: training leaves these objects
out of every split, ``check`` leaves them out of its verdict; both say so. A failure that kept
the object's earlier grid (``grid_kept``: a rerun could not voxelize a mesh changed or gone
since, and kept the grid made from the mesh as rendered) is no such row."""
from __future__ import annotations

from pathlib import Path

__all__ = ["voxelize_failures"]


def voxelize_failures(index: dict) -> set[tuple[str, int]]:
    """``{(shard file name, row)}`` of the placeholder grids of the dataset whose parsed
    ``index.json`` is ``index`` (module doc)."""
    return {(Path(str(f.get("shard"))).name, int(f["row"])) for f in index.get("failures", [])
            if f.get("stage") == "voxelize" and isinstance(f.get("row"), int) and not f.get("grid_kept")}
