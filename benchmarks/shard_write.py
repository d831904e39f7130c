"""HDF5 settings of the shards: write time, file size and read time per compression and chunking.

    python benchmarks/shard_write.py SHARD_DIR [--repeat 3]

Takes the arrays of an existing shard directory (e.g. the output of ``sc3d-data render
--voxelize``), writes them again with each candidate setting (``h5py``, one dataset per array
as ``sc3d_data.io.shards.write_shard`` does) and reports, per setting: CPU ms to write one object
(stack + compress + write, the best of ``--repeat``), bytes per object, CPU ms to read one whole
object (every array) and one view (image + mask, as the training loader needs), and whether the
arrays read back are bit-identical. CPU time, because the machine is shared.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import h5py  # noqa: E402
import numpy as np  # noqa: E402

from sc3d_data.io.shards import STRING_FIELDS, shard_files  # noqa: E402

#: name -> (dataset keyword arguments, chunk rule: "object" = one object per chunk,
#: "view" = one view per chunk for the per-view image arrays)
SETTINGS = {
    "gzip 4 + shuffle, object chunks (current)": ({"compression": "gzip", "compression_opts": 4, "shuffle": True}, "object"),
    "gzip 1 + shuffle, object chunks": ({"compression": "gzip", "compression_opts": 1, "shuffle": True}, "object"),
    "gzip 6 + shuffle, object chunks": ({"compression": "gzip", "compression_opts": 6, "shuffle": True}, "object"),
    "gzip 4, no shuffle, object chunks": ({"compression": "gzip", "compression_opts": 4}, "object"),
    "lzf + shuffle, object chunks": ({"compression": "lzf", "shuffle": True}, "object"),
    "no compression, object chunks": ({}, "object"),
    "gzip 4 + shuffle, view chunks": ({"compression": "gzip", "compression_opts": 4, "shuffle": True}, "view"),
    "gzip 1 + shuffle, view chunks": ({"compression": "gzip", "compression_opts": 1, "shuffle": True}, "view"),
}
VIEW_ARRAYS = ("images", "masks", "depth")


def load_arrays(shard_dir: Path) -> dict[str, np.ndarray]:
    """All numeric per-object arrays of the first shard file."""
    with h5py.File(shard_files(shard_dir)[0], "r") as f:
        return {k: f[k][()] for k in f if k not in STRING_FIELDS}


def write(path: Path, arrays: dict[str, np.ndarray], kwargs: dict, chunking: str) -> None:
    with h5py.File(path, "w") as f:
        for name, a in arrays.items():
            per_view = chunking == "view" and name in VIEW_ARRAYS
            chunks = (1, 1) + a.shape[2:] if per_view else (1,) + a.shape[1:]
            f.create_dataset(name, data=np.stack(list(a)), chunks=chunks, **kwargs)


def cpu_ms(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t = time.process_time()
        fn()
        best = min(best, (time.process_time() - t) * 1e3)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("shards", type=Path)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    arrays = load_arrays(args.shards)
    n = len(arrays["images"])
    print(f"{n} objects, arrays {sorted(arrays)}; CPU ms (best of {args.repeat}); "
          f"raw {sum(a.nbytes for a in arrays.values()) / n / 1024:.0f} KiB per object\n")
    print("| setting | write ms/object | KiB/object | read object ms | read one view ms | identical |")
    print("|---|---|---|---|---|---|")
    rng = np.random.default_rng(0)
    rows, views = rng.integers(0, n, 50), rng.integers(0, arrays["images"].shape[1], 50)
    with tempfile.TemporaryDirectory() as tmp:
        for name, (kwargs, chunking) in SETTINGS.items():
            path = Path(tmp) / "s.h5"
            w = cpu_ms(lambda: write(path, arrays, kwargs, chunking), args.repeat)
            size = os.path.getsize(path)
            with h5py.File(path, "r") as f:
                same = all(np.array_equal(f[k][()], a) and f[k].dtype == a.dtype for k, a in arrays.items())
                ro = cpu_ms(lambda: [f[k][r] for r in rows for k in arrays], 1) / len(rows)
                rv = cpu_ms(lambda: [f[k][r, v] for r, v in zip(rows, views) for k in ("images", "masks")],
                            1) / len(rows)
            print(f"| {name} | {w / n:.2f} | {size / n / 1024:.1f} | {ro:.2f} | {rv:.3f} | {same} |")


if __name__ == "__main__":
    main()
