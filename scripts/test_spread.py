"""Rerun the tests that train a model and assert what it learnt under several seeds and torch
thread counts, and print each asserted figure's spread beside its bound.

    python scripts/test_spread.py [--seeds 0-9] [--threads 1,2] [--tests -m learnt] [--keep FILE]

Each (threads, seed) pair is one ``pytest`` process: ``OMP_NUM_THREADS=T`` (torch reads it at
import) and ``--train-seed S`` (tests/conftest.py: the seed of the shared training run and of every
``learnt`` test). The tests report each figure they assert through ``assert_learnt``, which
appends it to the file named by ``$SC3D_LEARNT_FIGURES``; this script reads that file back.

The table has one row per figure: its bound, min / median / max over all runs, the worst value's
margin to the bound (negative: some run failed), and the median per thread count. A bound is
sound when the worst run keeps a margin the spread makes plausible for an unseen CPU; write the
table into the test's docstring when you change a bound. Exits 1 when any run failed.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def parse_seeds(text: str) -> list[int]:
    """``"0-9"`` -> 0..9, ``"0,3,7"`` -> [0, 3, 7]."""
    if "-" in text:
        lo, hi = (int(x) for x in text.split("-"))
        return list(range(lo, hi + 1))
    return [int(x) for x in text.split(",")]


def run_once(seed: int, threads: int, tests: list[str], figures: Path) -> tuple[int, float]:
    """One pytest process; returns (exit code, seconds)."""
    env = {**os.environ, "OMP_NUM_THREADS": str(threads), "SC3D_LEARNT_FIGURES": str(figures)}
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-n", "0",
                           f"--train-seed={seed}", *tests], cwd=REPO, env=env,
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if proc.returncode not in (0, 1):
        print(proc.stdout[-3000:])
    return proc.returncode, time.perf_counter() - t0


def margin(row: dict) -> float:
    """How far a value is on the passing side of its bound (negative: it failed)."""
    return row["value"] - row["bound"] if row["op"] in (">", ">=") else row["bound"] - row["value"]


def print_table(rows: list[dict]) -> None:
    by_name: dict[str, list[dict]] = {}
    for r in rows:
        by_name.setdefault(r["name"], []).append(r)
    threads = sorted({r["threads"] for r in rows})
    head = ["figure", "bound", "runs", "min", "median", "max", "worst margin"] + [f"median {t} thr" for t in threads]
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for name, rs in by_name.items():
        vals = [r["value"] for r in rs]
        cells = [name, f"{rs[0]['op']} {rs[0]['bound']:g}", str(len(rs)), f"{min(vals):.3g}",
                 f"{statistics.median(vals):.3g}", f"{max(vals):.3g}", f"{min(margin(r) for r in rs):+.3g}"]
        cells += [f"{statistics.median([r['value'] for r in rs if r['threads'] == t]):.3g}"
                  if any(r["threads"] == t for r in rs) else "-" for t in threads]
        print("| " + " | ".join(cells) + " |")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="0-9", help="'0-9' or '0,3,7' (default 0-9)")
    ap.add_argument("--threads", default="1,2", help="torch thread counts (default 1,2)")
    ap.add_argument("--tests", default="-m learnt", help="what pytest runs (default: '-m learnt')")
    ap.add_argument("--keep", type=Path, default=None, help="also write every figure as JSON lines here")
    args = ap.parse_args()
    seeds, threads = parse_seeds(args.seeds), [int(t) for t in args.threads.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        figures = Path(tmp) / "figures.jsonl"
        figures.touch()
        failed = []
        for t in threads:
            for s in seeds:
                code, secs = run_once(s, t, args.tests.split(), figures)
                print(f"threads {t} seed {s}: {'passed' if code == 0 else 'FAILED'} in {secs:.0f} s", flush=True)
                if code:
                    failed.append((t, s))
        rows = [json.loads(line) for line in figures.read_text().splitlines() if line.strip()]
    if args.keep:
        args.keep.write_text("".join(json.dumps(r) + "\n" for r in rows))
    print()
    print_table(rows)
    print(f"\n{len(seeds) * len(threads) - len(failed)} of {len(seeds) * len(threads)} runs passed"
          + (f"; failed (threads, seed): {failed}" if failed else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
