"""The two measuring scripts `scripts/gpu_check.sh` runs for issues 21 and 22 on a GPU machine,
checked here on the CPU: `benchmarks/compare_curves.py` (is the compiled run's loss curve the
eager one's, against a third run's seed-to-seed noise) and `benchmarks/corpus_size.py`'s
collection of N objects. Their verdicts decide whether a GPU figure is called met, so each is
tested on a case whose answer is known by construction."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def write_metrics(run: Path, totals: list[float], rate: float = 100.0, every: int = 10) -> Path:
    """``run/metrics.csv`` with the total loss ``totals[i]`` at step ``every * (i + 1) - 1``."""
    run.mkdir(parents=True)
    lines = ["step,phase,total,samples_per_s"]
    lines += [f"{every * (i + 1) - 1},supervised,{t},{rate}" for i, t in enumerate(totals)]
    (run / "metrics.csv").write_text("\n".join(lines) + "\n")
    return run


def compare(a: Path, b: Path, c: Path, *extra: str) -> str:
    out = subprocess.run([sys.executable, str(REPO / "benchmarks" / "compare_curves.py"), str(a), str(b),
                          "--noise", str(c), *extra], capture_output=True, text=True, check=True)
    return out.stdout


def test_compare_curves_tells_the_same_curve_from_a_different_one(tmp_path):
    """B and C differ by a seed's noise (±0.1 around the same decay). A equal to B is the same
    curve; A that stays 1.0 above B (a compiled step that trains differently) is not."""
    decay = [4.0 * 0.99 ** i for i in range(40)]
    b = write_metrics(tmp_path / "b", decay, rate=4000)
    c = write_metrics(tmp_path / "c", [x + (0.1 if i % 2 else -0.1) for i, x in enumerate(decay)])
    same = compare(write_metrics(tmp_path / "a_same", decay), b, c)
    assert "same curve" in same and "DIFFERENT" not in same
    differ = compare(write_metrics(tmp_path / "a_off", [x + 1.0 for x in decay]), b, c)
    assert "DIFFERENT curves" in differ


def test_compare_curves_projects_the_paper_run_from_the_compiled_one(tmp_path):
    """400 steps of 48 logged at 4,000 samples/s, 30 s of wall time: 20,000 steps take
    30 s + 19,600 x 48 / 4,000 = 265.2 s."""
    b = write_metrics(tmp_path / "b", [1.0] * 40, rate=4000)
    out = compare(b, b, b, "--project-steps", "20000", "--wall-b", "30", "--batch-size", "48")
    assert "20000 steps of 48: 265 s" in out


def test_corpus_lists_n_distinct_objects_pass_after_pass(tmp_path):
    """25 objects from 11 meshes: 3 passes (11 + 11 + 3), every path distinct, each a link to
    one of the meshes, the first pass holding each mesh once."""
    sys.path.insert(0, str(REPO / "benchmarks"))
    try:
        from corpus_size import corpus
    finally:
        sys.path.remove(str(REPO / "benchmarks"))
    root = REPO / "assets" / "sample_meshes"
    from sc3d_data.io.meshes import MESH_SUFFIXES

    paths = sorted(p for p in root.rglob("*") if p.suffix.lower() in MESH_SUFFIXES)
    assert len(paths) == 11
    dest = corpus(paths, root, 25, tmp_path / "m")
    links = sorted(p for p in dest.rglob("*") if p.is_symlink())
    assert len(links) == 25 == len({str(p) for p in links})
    assert {p.resolve() for p in links} == {p.resolve() for p in paths}
    first = [p for p in links if p.relative_to(dest).parts[0] == "c0"]
    assert sorted(p.resolve() for p in first) == sorted(p.resolve() for p in paths)


@pytest.mark.parametrize("bad", ["0", "x"])
def test_corpus_size_refuses_sizes_it_cannot_list(tmp_path, bad):
    out = subprocess.run([sys.executable, str(REPO / "benchmarks" / "corpus_size.py"), "--meshes",
                          str(REPO / "assets" / "sample_meshes"), "--sizes", bad], capture_output=True, text=True)
    assert out.returncode != 0 and "Traceback" not in out.stderr


def test_pipeline_compare_runs_each_trees_own_code_in_the_workers(tmp_path):
    """``pipeline_compare.py`` runs an older tree against this one. Its render workers are forked
    from a forkserver, which (Python 3.11) took sc3d from the working directory, not from the
    tree: both "trees" ran this code in their workers, and a changed voxelizer showed "values
    differing: none". Here the old tree is this one with every voxel grid emptied in the worker
    (``voxelize_canonical`` returns zeros): the comparison must see the voxels differ and
    nothing else."""
    import shutil

    old = tmp_path / "old"
    shutil.copytree(REPO / "sc3d_data", old / "sc3d_data")  # numba caches too: no compiling
    job = old / "sc3d_data" / "pipeline" / "jobs" / "voxel_job.py"
    text = job.read_text()
    marker = "    return voxelize_triangles(apply_transform(vertices, to_canonical), faces, resolution)\n"
    assert marker in text
    job.write_text(text.replace(marker, "    return np.zeros((resolution,) * 3, dtype=bool)\n"))
    meshes = tmp_path / "m" / "chair"
    meshes.mkdir(parents=True)
    shutil.copy(REPO / "assets" / "sample_meshes" / "chair" / "chair2_blendswap.glb", meshes)
    out = subprocess.run([sys.executable, str(REPO / "benchmarks" / "pipeline_compare.py"), str(old),
                          str(tmp_path / "m"), "--repeat", "1", "--workers", "1"],
                         capture_output=True, text=True, check=True, cwd=REPO).stdout
    line = [ln for ln in out.splitlines() if ln.startswith("values differing")]
    assert len(line) == 1 and line[0].startswith("values differing between old and new: voxels: "), out
    assert "images" not in line[0] and "masks" not in line[0]
