"""Old against new voxelizer in one process: CPU ms per mesh and whether the grids are identical.

    git archive <OLD_COMMIT> | tar -x -C /tmp/old
    python benchmarks/voxelize_compare.py /tmp/old [MESH_FOLDER] [--repeat 3]

The ``sc3d_data`` package of the old source tree is imported under another name
(``sc3d_data_old``). Both voxelizers then run on the same canonical triangles of every mesh
(loaded and normalised as ``benchmarks/voxelize.py`` does), interleaved and each ``--repeat``
times per mesh, and the fastest run counts. Process CPU time is used because both run on one
thread and the machine may be shared. Prints the median, p90 and mean and the number of meshes
whose grids differ.
"""
from __future__ import annotations

import importlib.util
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import numpy as np  # noqa: E402

from sc3d_data.voxel import voxelize as new  # noqa: E402
from sc3d_data.formats.discover import discover_meshes  # noqa: E402
from sc3d_data.io.meshes import load_mesh_triangles  # noqa: E402
from sc3d_data.geometry.normalize import apply_transform, to_canonical_transform  # noqa: E402
from old_tree import old_tree_parser  # noqa: E402  (benchmarks/old_tree.py)


def import_old(tree: Path):
    """The voxelize module of another source tree, imported as ``sc3d_data_old...``:
    ``sc3d_data/voxel/voxelize.py`` (since the layering of issue 12) or ``sc3d_data/voxelize.py``."""
    pkg = tree / "sc3d_data"
    spec = importlib.util.spec_from_file_location("sc3d_data_old", pkg / "__init__.py",
                                                  submodule_search_locations=[str(pkg)])
    module = importlib.util.module_from_spec(spec)
    sys.modules["sc3d_data_old"] = module
    spec.loader.exec_module(module)
    name = "voxel.voxelize" if (pkg / "voxel" / "voxelize.py").is_file() else "voxelize"
    return importlib.import_module(f"sc3d_data_old.{name}")


def main() -> None:
    ap = old_tree_parser(__doc__)
    ap.add_argument("--resolution", type=int, default=32)
    args = ap.parse_args()
    old = import_old(args.old_tree)
    meshes = []
    for e in discover_meshes(args.meshes)[0]:
        try:
            v, f = load_mesh_triangles(e.path)
        except Exception as ex:  # noqa: BLE001
            print(f"skip {e.path}: {ex}", file=sys.stderr)
            continue
        meshes.append((apply_transform(v, to_canonical_transform(v, f)), f))
    if not meshes:
        sys.exit(f"{args.meshes}: no meshes")
    G = args.resolution
    for mod in (old, new):  # compile / load the cached kernels
        mod.voxelize_triangles(*meshes[0], G)
    ms = {"before": [], "after": []}
    differ = 0
    for v, f in meshes:
        best, grids = {}, {}
        for _ in range(args.repeat):
            for key, mod in (("before", old), ("after", new)):
                c = time.process_time()
                grids[key] = mod.voxelize_triangles(v, f, G)
                best[key] = min(best.get(key, float("inf")), (time.process_time() - c) * 1e3)
        for key in ms:
            ms[key].append(best[key])
        differ += not np.array_equal(grids["before"], grids["after"])
    print(f"{len(meshes)} meshes, {G}^3, CPU ms per mesh (fastest of {args.repeat}, interleaved)")
    print("| | median | p90 | mean |\n|---|---|---|---|")
    for key, t in ms.items():
        print(f"| {key} | {np.median(t):.2f} | {np.percentile(t, 90):.2f} | {np.mean(t):.2f} |")
    print(f"meshes whose grids differ: {differ} of {len(meshes)}")


if __name__ == "__main__":
    main()
