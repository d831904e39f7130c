"""(a module, not run directly) The command line shared by the scripts that compare an older
source tree of sc3d with the current one (``voxelize_compare.py``, ``pipeline_compare.py``)."""
from __future__ import annotations

import argparse
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def old_tree_parser(doc: str) -> argparse.ArgumentParser:
    """A parser described by ``doc``'s first line with the positional ``old_tree`` (a source
    tree holding ``sc3d_data/``, e.g. from ``git archive``), ``meshes`` (default
    ``../shared/meshes``) and ``--repeat`` (default 3)."""
    ap = argparse.ArgumentParser(description=doc.split("\n")[0])
    ap.add_argument("old_tree", type=Path, help="source tree of the old version (holds sc3d_data/)")
    ap.add_argument("meshes", nargs="?", type=Path, default=REPO.parent / "shared" / "meshes")
    ap.add_argument("--repeat", type=int, default=3)
    return ap
