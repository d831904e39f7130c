"""Fault-injection study of ``sc3d-data`` / ``sc3d-train`` (issue 11): a corpus of real meshes
with ~5% bad files, signals to the driver and to a worker, corrupted shards, two writers at
once, a full disk, a crafted checkpoint and a crafted index. Prints one table row per scenario
(bad inputs tried, faults injected, objects lost, tracebacks seen) and every failure reason.

Objects lost = good meshes of the corpus that are not in the final dataset after the scenario
and one plain rerun of the same command (the documented recovery). Targets: 0 lost in every
scenario, no traceback reaches the user, every failure names its file, nothing from a
checkpoint or an index runs or writes outside its folder.

    python benchmarks/faults.py                          # ~1,000 files, 24 views (long)
    python benchmarks/faults.py --files 120 --views 4    # reduced run (minutes)

The corpus is built from a folder of meshes (``--meshes``, default /work/shared/meshes, else
the bundled samples): good files are symlinks with distinct names to its meshes (cycled up to
``--files``), bad files are generated (random bytes, truncated GLB, NaN / 1e300 / outlier
vertices, zero area, a missing texture, a folder and a FIFO named like meshes, a broken
symlink) plus files that must render with a warning (non-UTF-8 OBJ, missing .mtl, a texture
outside the folder). The disk-full scenario needs ``unshare -rm`` (user + mount namespace).
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
DATA = [sys.executable, "-c", "from sc3d_cli.data import main; main()"]
TRAIN = [sys.executable, "-c", "from sc3d_cli.train import main; main()"]
ENV = dict(os.environ, PYTHONPATH=f"{REPO}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
CUBE = ("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nv 0 0 1\nv 1 0 1\nv 0 1 1\nv 1 1 1\n"
        "f 1 2 4\nf 1 4 3\nf 5 7 8\nf 5 8 6\nf 1 5 6\nf 1 6 2\nf 3 4 8\nf 3 8 7\nf 1 3 7\nf 1 7 5\nf 2 6 8\nf 2 8 4\n")


# ----------------------------------------------------------------------------- corpus
def _bad_file(kind: str, folder: Path, i: int, sources: list[Path]) -> tuple[Path, str]:
    """Create one bad (or tricky) input; returns (path, expected: fail | skip | warn)."""
    import numpy as np

    rng = np.random.default_rng(i)
    name = f"zz_{kind}_{i:04d}"
    if kind.startswith("random"):
        p = folder / f"{name}.{kind.split('_')[1]}"
        p.write_bytes(rng.integers(0, 256, 3000, dtype=np.uint8).tobytes())
        return p, "fail"
    if kind == "empty":
        (p := folder / f"{name}.obj").write_bytes(b"")
        return p, "fail"
    if kind == "truncated_glb":
        src = sources[i % len(sources)].read_bytes()
        (p := folder / f"{name}.glb").write_bytes(src[:len(src) // 3])
        return p, "fail"
    if kind == "nan":
        (p := folder / f"{name}.obj").write_text(CUBE.replace("v 1 1 1", "v 1 nan 1"))
        return p, "fail"
    if kind == "huge":
        (p := folder / f"{name}.obj").write_text(CUBE.replace("v 1 1 1", "v 1e300 1 1"))
        return p, "fail"
    if kind == "outlier":
        (p := folder / f"{name}.obj").write_text(CUBE + "v 1e9 0 0\nf 1 2 9\n")
        return p, "fail"
    if kind == "flat":
        (p := folder / f"{name}.obj").write_text("v 0 0 0\nv 1 1 1\nv 2 2 2\nf 1 2 3\n")
        return p, "fail"
    if kind == "missing_texture":
        (folder / f"{name}.mtl").write_text("newmtl m\nmap_Kd nowhere.png\n")
        (p := folder / f"{name}.obj").write_text(f"mtllib {name}.mtl\nusemtl m\n" + CUBE)
        return p, "fail"
    if kind == "folder":
        (p := folder / f"{name}.obj").mkdir()
        return p, "skip"
    if kind == "fifo":
        os.mkfifo(p := folder / f"{name}.obj")
        return p, "skip"
    if kind == "broken_symlink":
        (p := folder / f"{name}.glb").symlink_to(folder / "does_not_exist.glb")
        return p, "fail"
    if kind == "latin1":
        (p := folder / f"{name}.obj").write_bytes("# caf\xe9\n".encode("latin-1") + CUBE.encode())
        return p, "good"
    if kind == "missing_mtl":
        (p := folder / f"{name}.obj").write_text("mtllib gone.mtl\nusemtl m\n" + CUBE)
        return p, "warn"
    if kind == "outside_texture":
        tex = folder.parent.parent / "outside.png"
        if not tex.exists():
            from PIL import Image

            Image.new("RGB", (8, 8), (10, 200, 10)).save(tex)
        (folder / f"{name}.mtl").write_text(f"newmtl m\nmap_Kd {tex}\n")
        (p := folder / f"{name}.obj").write_text(f"mtllib {name}.mtl\nusemtl m\n" + CUBE)
        return p, "warn"
    raise ValueError(kind)


BAD_KINDS = ["random_obj", "random_off", "random_stl", "random_ply", "random_glb", "empty", "truncated_glb",
             "nan", "huge", "outlier", "flat", "missing_texture", "folder", "fifo", "broken_symlink",
             "latin1", "missing_mtl", "outside_texture"]


def build_corpus(root: Path, meshes: Path, n_files: int, bad_fraction: float) -> dict[str, str]:
    """``root/meshes/CATEGORY/...``: good symlinks + bad files; returns {file name: expected}."""
    sources = sorted(p for p in meshes.rglob("*.glb") if p.is_file())
    if not sources:
        raise SystemExit(f"{meshes}: no .glb meshes")
    n_bad = max(len(BAD_KINDS), round(n_files * bad_fraction))
    expected = {}
    cats = sorted({p.parent.name for p in sources})
    for i in range(n_files - n_bad):
        src = sources[i % len(sources)]
        folder = root / "meshes" / src.parent.name
        folder.mkdir(parents=True, exist_ok=True)
        link = folder / f"{src.stem}__{i:04d}.glb"
        link.symlink_to(src)
        expected[link.name] = "good"
    for i in range(n_bad):
        folder = root / "meshes" / cats[i % len(cats)]
        folder.mkdir(parents=True, exist_ok=True)
        p, what = _bad_file(BAD_KINDS[i % len(BAD_KINDS)], folder, i, sources)
        expected[p.name] = what
    return expected


# ----------------------------------------------------------------------------- running commands
class Log:
    """Every command's output, to count tracebacks and collect one-line errors."""

    def __init__(self):
        self.tracebacks, self.errors, self.crashes = 0, [], 0

    def note(self, out: str, rc: int) -> None:
        self.tracebacks += out.count("Traceback")
        self.errors += [ln for ln in out.splitlines() if ln.startswith("Error:")]
        self.crashes += rc in (-11, 139, -6, 134)


LOG = Log()


def run(cmd: list[str], timeout: float = 3600, prefix: list[str] | None = None) -> tuple[int, str]:
    r = subprocess.run((prefix or []) + cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                       env=ENV, timeout=timeout, cwd=REPO)
    LOG.note(r.stdout, r.returncode)
    return r.returncode, r.stdout


def render_cmd(args, meshes: Path, out: Path, extra=()) -> list[str]:
    return DATA + ["render", "--meshes", str(meshes), "--out", str(out), "--views", str(args.views),
                   "--objects-per-shard", str(args.objects_per_shard), "--workers", str(args.workers),
                   "--no-progress", "--timeout", "60", "--voxelize", *extra]


def start(cmd: list[str]) -> subprocess.Popen:
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=ENV, cwd=REPO,
                            start_new_session=True)


def finish(p: subprocess.Popen, timeout: float = 3600) -> tuple[int, str]:
    out, _ = p.communicate(timeout=timeout)
    LOG.note(out, p.returncode)
    return p.returncode, out


def wait_for_shards(out: Path, n: int, proc: subprocess.Popen, timeout: float = 1800) -> bool:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout and proc.poll() is None:
        try:
            if len(json.loads((out / "index.json").read_text()).get("shards", [])) >= n:
                return True
        except (OSError, ValueError):
            pass
        time.sleep(0.2)
    return False


def index_objects(out: Path) -> set[str]:
    try:
        index = json.loads((out / "index.json").read_text())
    except (OSError, ValueError):
        return set()
    return {Path(o["source"]).name for o in index.get("objects", [])}


def lost(expected: dict[str, str], out: Path) -> int:
    have = index_objects(out)
    return sum(1 for name, what in expected.items() if what in ("good", "warn") and name not in have)


# ----------------------------------------------------------------------------- scenarios
def scenario_corpus(args, work, meshes, expected, rows, reasons):
    out = work / "ref"
    rc, text = run(render_cmd(args, meshes, out))
    index = json.loads((out / "index.json").read_text())
    accounted = {Path(f["source"]).name for f in index["failures"]} | {Path(s["source"]).name for s in index["skipped"]}
    warned = {Path(w["source"]).name for w in index["warnings"]}
    bad = {n: w for n, w in expected.items() if w != "good" or n.startswith("zz_")}
    unaccounted = [n for n, w in bad.items() if (w in ("fail", "skip") and n not in accounted)
                   or (w == "warn" and n not in warned)]
    # the line `sc3d-data info` prints for each: "SOURCE: REASON"; both parts must be there
    unnamed = [f for f in index["failures"] + index["skipped"]
               if Path(f["source"]).name not in f"{f['source']}: {f.get('reason', '')}" or not f.get("reason")]
    for f in index["failures"] + index["skipped"]:
        reasons[_reason_kind(f["reason"])].append(f"{Path(f['source']).name}: {f['reason'].split(': ', 1)[-1]}")
    for w in index["warnings"]:
        reasons["warning: " + _reason_kind(w["warning"])].append(w["warning"].split(": ", 1)[-1][:140])
    rows.append(("corpus render", len(bad), 0, lost(expected, out),
                 f"rc {rc}; {len(index['objects'])} rendered, {len(index['failures'])} failed, "
                 f"{len(index['skipped'])} skipped, {len(index['warnings'])} warnings; "
                 f"bad inputs unaccounted {len(unaccounted)} {unaccounted[:3]}; reasons without file {len(unnamed)}"))
    return out


def _reason_kind(reason: str) -> str:
    r = reason.split(": ", 1)[-1]
    r = re.sub(r"/\S+", "PATH", r)
    r = re.sub(r"\d[\d.e+,-]*", "N", r)
    return r[:90]


def scenario_signal(args, work, meshes, expected, rows, ref, sig: str, target: str):
    out = work / f"{target}_{sig}"
    p = start(render_cmd(args, meshes, out))
    injected = 0
    if wait_for_shards(out, 1, p):
        if target == "driver" and sig == "SIGINT":  # Ctrl-C: the whole foreground group
            os.killpg(p.pid, signal.SIGINT)
            injected = 1
        elif target == "driver":
            os.kill(p.pid, signal.SIGKILL)
            injected = 1
        else:
            import psutil

            workers = [c for c in psutil.Process(p.pid).children(recursive=True)
                       if "spawn_main" in " ".join(c.cmdline()) and "resource_tracker" not in " ".join(c.cmdline())]
            if workers:
                workers[0].send_signal(signal.SIGKILL)
                injected = 1
    rc1, text1 = finish(p)
    if sig == "SIGKILL" and target == "driver":  # orphaned workers exit on EOF; give them a moment
        time.sleep(1)
    killed_fail = sum("killed by signal 9" in ln for ln in (out / "index.json").read_text().splitlines()) \
        if (out / "index.json").is_file() else 0
    rc2, text2 = run(render_cmd(args, meshes, out))
    same = _same_shards(ref, out)
    rows.append((f"{sig} to {target}", 0, injected, lost(expected, out),
                 f"first rc {rc1}; {killed_fail} objects failed by the kill; rerun rc {rc2}: "
                 f"{_summary(text2)}; shards identical to the uninterrupted run: {same}"))


def _summary(text: str) -> str:
    m = re.search(r"done \d+, resumed \d+(, retried \d+)?, skipped \d+, failed \d+", text)
    return m.group(0) if m else text.strip().splitlines()[-1][:120] if text.strip() else ""


def _same_shards(a: Path, b: Path) -> bool:
    ia, ib = (json.loads((x / "index.json").read_text()) for x in (a, b))
    return [(s["file"], s.get("sha256")) for s in ia["shards"]] == [(s["file"], s.get("sha256")) for s in ib["shards"]]


def scenario_corruption(args, work, meshes, expected, rows, ref):
    out = work / "corrupt"
    shutil.copytree(ref, out)
    shards = sorted(out.glob("shard-*.h5"))
    injected = 0
    if len(shards) >= 1:
        data = shards[0].read_bytes()
        shards[0].write_bytes(data[:len(data) // 2])
        injected += 1
    if len(shards) >= 2:
        with open(shards[1], "r+b") as f:
            f.seek(shards[1].stat().st_size // 2)
            b = f.read(16)
            f.seek(-16, 1)
            f.write(bytes(x ^ 0x5A for x in b))
        injected += 1
    rc_info, text_info = run(DATA + ["info", str(out)])
    rc_ver, text_ver = run(DATA + ["info", str(out), "--verify"])
    named = sum(s.name in text_ver for s in shards[:2])
    rc_check, text_check = run(DATA + ["check", str(out), "--no-progress"])
    rc_fit, text_fit = run(TRAIN + ["fit", "--shards", str(out), "--out", str(work / "fit_corrupt"), "--steps", "1",
                                    "--tiny", "--batch-size", "2", "--no-progress"])
    rc, text = run(render_cmd(args, meshes, out))
    rc_after, _ = run(DATA + ["info", str(out), "--verify"])
    rows.append(("truncate + flip bytes in shards", 0, injected, lost(expected, out),
                 f"info rc {rc_info}, info --verify rc {rc_ver} naming {named}/{injected} shards; "
                 f"check rc {rc_check} ({_first_error(text_check)[:100]}); fit rc {rc_fit} "
                 f"({_first_error(text_fit)}); rerun: {_summary(text)}; verify after rerun rc {rc_after}"))


def _first_error(text: str) -> str:
    errs = [ln for ln in text.splitlines() if ln.startswith("Error:")]
    return (errs[0][:150] if errs else "no error line")


def scenario_concurrent(args, work, meshes, expected, rows, ref):
    out = work / "concurrent"
    a = start(render_cmd(args, meshes, out))
    time.sleep(0.5)
    b = start(render_cmd(args, meshes, out))
    (rc_a, text_a), (rc_b, text_b) = finish(a), finish(b)
    refused = [t for t in (text_a, text_b) if "is writing to this folder" in t]
    rc_v, _ = run(DATA + ["info", str(out), "--verify"])
    rows.append(("two renders into one --out", 0, 1, lost(expected, out),
                 f"rc {rc_a}/{rc_b}; refused with one line: {len(refused)} ({_first_error(refused[0]) if refused else '-'}); "
                 f"verify rc {rc_v}; identical to the reference: {_same_shards(ref, out)}"))


def scenario_disk_full(args, work, meshes, expected, rows, ref):
    if not _tmpfs_ok():
        rows.append(("disk full (tmpfs)", 0, 0, "-", "skipped: no user+mount namespace here"))
        return
    size_kb = max(64, sum(p.stat().st_size for p in ref.glob("shard-*.h5")) // 1024 // 3)
    cmd = " ".join(f"'{c}'" for c in render_cmd(args, meshes, Path("$T/out")))
    cmd = cmd.replace("'$T/out'", '"$T/out"')
    script = (f"set -u; T=$(mktemp -d); mount -t tmpfs -o size={size_kb}k tmpfs $T; cd {REPO}\n"
              f"{cmd}; echo \"RC1=$?\"; echo \"TMP=$(ls $T/out | grep -c '\\.tmp$')\"\n"
              f"mount -o remount,size={size_kb * 8}k $T\n{cmd}; echo \"RC2=$?\"\n"
              f"cp $T/out/index.json {work}/diskfull_index.json\n")
    rc, text = run(["unshare", "-rm", "bash", "-c", script])
    out = work / "diskfull"
    out.mkdir(exist_ok=True)
    if (work / "diskfull_index.json").is_file():
        shutil.copy(work / "diskfull_index.json", out / "index.json")
    first = text.split("RC1=")[0]
    rows.append(("disk full (tmpfs)", 0, 1, lost(expected, out),
                 f"{size_kb} kB tmpfs: {re.search(r'RC1=(-?[0-9]+)', text).group(0) if 'RC1=' in text else '?'}, "
                 f"{_first_error(first)}; temp files left {re.search(r'TMP=([0-9]+)', text).group(1) if 'TMP=' in text else '?'}; "
                 f"after freeing space {re.search(r'RC2=(-?[0-9]+)', text).group(0) if 'RC2=' in text else '?'}: "
                 f"{_summary(text.split('RC1=')[-1])}"))


def _tmpfs_ok() -> bool:
    if not shutil.which("unshare"):
        return False
    return subprocess.run(["unshare", "-rm", "sh", "-c", "mount -t tmpfs -o size=1m tmpfs /mnt"],
                          capture_output=True).returncode == 0


def scenario_fit_disk_full(work, rows, ref):
    """``fit`` whose checkpoint does not fit: one line, no temp file, ``--resume`` continues from
    the newest complete checkpoint and ends with the same weights as an uninterrupted run."""
    if not _tmpfs_ok():
        rows.append(("fit checkpoint, disk full", 0, 0, "-", "skipped: no user+mount namespace here"))
        return
    fit = ["fit", "--shards", str(ref), "--steps", "6", "--checkpoint-every", "2", "--tiny", "--batch-size", "4",
           "--no-progress", "--seed", "0", "--log-every", "1", "--split", "train"]
    rc_a, text_a = run(TRAIN + fit + ["--out", str(work / "fitA")])
    if rc_a != 0:
        rows.append(("fit checkpoint, disk full", 0, 0, "-", f"reference fit failed: {_first_error(text_a)}"))
        return
    size = (work / "fitA" / "checkpoints" / "step_000002.pt").stat().st_size
    kb = int((3.5 * size + 600_000) // 1024)  # step 2 + last.pt + step 4 fit, last.pt's copy does not
    q = lambda args: " ".join(f"'{a}'" for a in args)  # noqa: E731
    script = (f"set -u; T=$(mktemp -d); mount -t tmpfs -o size={kb}k tmpfs $T; cd {REPO}\n"
              f"{q(TRAIN + fit)} --out $T/run; echo \"RC1=$?\"\n"
              f"echo \"FILES=$(ls $T/run/checkpoints | tr '\\n' ' ')\"\n"
              f"mount -o remount,size={kb * 4}k $T\n"
              f"{q(TRAIN)} fit --out $T/run --resume --no-progress; echo \"RC2=$?\"\n"
              f"cp $T/run/checkpoints/last.pt {work}/fitB_last.pt\n")
    rc, text = run(["unshare", "-rm", "bash", "-c", script])
    diff = "?"
    if (work / "fitB_last.pt").is_file():
        from sc3d_train.loop.checkpoint import load_checkpoint

        a = load_checkpoint(work / "fitA" / "checkpoints" / "last.pt")["model"]
        b = load_checkpoint(work / "fitB_last.pt")["model"]
        diff = max(float((a[k].float() - b[k].float()).abs().max()) for k in a)
    first = text.split("RC1=")[0]
    m = lambda pat: (re.search(pat, text).group(1) if re.search(pat, text) else "?")  # noqa: E731
    rc1, files, rc2 = m(r"RC1=(-?[0-9]+)"), m(r"FILES=([^\n]*)"), m(r"RC2=(-?[0-9]+)")
    rows.append(("fit checkpoint, disk full", 0, 1, 0,
                 f"{kb} kB tmpfs: rc {rc1}, {_first_error(first)[:140]}; files left: {files}; "
                 f"--resume after freeing space rc {rc2}; max abs weight diff vs uninterrupted run {diff}"))


def scenario_checkpoint(work, rows):
    import torch

    marker = work / "checkpoint_code_ran"
    evil = work / "evil.pt"

    class Payload:
        def __reduce__(self):
            return (os.system, (f"touch {marker}",))

    torch.save({"model": {}, "config": {}, "x": Payload()}, evil)
    from PIL import Image

    Image.new("RGB", (64, 64), (255, 255, 255)).save(work / "img.png")
    rcs = []
    for cmd in (["eval", "--checkpoint", str(evil), "--shards", str(work / "ref"), "--out", str(work / "ev")],
                ["predict", "--checkpoint", str(evil), str(work / "img.png"), "--out", str(work / "pr")]):
        rc, text = run(TRAIN + cmd)
        rcs.append(f"{cmd[0]} rc {rc} ({_first_error(text)[:90]})")
    rows.append(("crafted checkpoint (eval, predict)", 1, 2, 0,
                 f"{'; '.join(rcs)}; code executed: {marker.exists()}"))


def scenario_index(work, rows):
    out = work / "traversal"
    shutil.copytree(work / "ref", out)
    victim = work / "victim"
    victim.mkdir()
    shutil.copy(next(out.glob("shard-*.h5")), victim / "shard-00000.h5")
    before = (victim / "shard-00000.h5").read_bytes()
    index = json.loads((out / "index.json").read_text())
    index["shards"][0]["file"] = "../victim/shard-00000.h5"
    (out / "index.json").write_text(json.dumps(index))
    rc, text = run(DATA + ["voxelize", str(out), "--overwrite", "--no-progress"])
    changed = (victim / "shard-00000.h5").read_bytes() != before
    rows.append(("index path ../victim (voxelize)", 1, 1, 0,
                 f"rc {rc} ({_first_error(text)[:110]}); file outside rewritten: {changed}"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--meshes", type=Path, default=Path("/work/shared/meshes"))
    ap.add_argument("--files", type=int, default=1000)
    ap.add_argument("--bad-fraction", type=float, default=0.05)
    ap.add_argument("--views", type=int, default=24)
    ap.add_argument("--objects-per-shard", type=int, default=32)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--keep", action="store_true", help="Keep the work folder.")
    args = ap.parse_args()
    meshes_src = args.meshes if args.meshes.is_dir() else REPO / "assets" / "sample_meshes"
    work = Path(tempfile.mkdtemp(prefix="sc3d_faults_"))
    t0 = time.monotonic()
    try:
        expected = build_corpus(work / "corpus", meshes_src, args.files, args.bad_fraction)
        meshes = work / "corpus" / "meshes"
        rows, reasons = [], {}
        from collections import defaultdict

        reasons = defaultdict(list)
        ref = scenario_corpus(args, work, meshes, expected, rows, reasons)
        for sig, target in (("SIGINT", "driver"), ("SIGKILL", "driver"), ("SIGKILL", "worker")):
            scenario_signal(args, work, meshes, expected, rows, ref, sig, target)
        scenario_corruption(args, work, meshes, expected, rows, ref)
        scenario_concurrent(args, work, meshes, expected, rows, ref)
        scenario_disk_full(args, work, meshes, expected, rows, ref)
        scenario_fit_disk_full(work, rows, ref)
        scenario_checkpoint(work, rows)
        scenario_index(work, rows)
        kinds = Counter(expected.values())
        print(f"corpus: {len(expected)} files from {meshes_src} ({kinds['good']} good, {kinds['fail']} bad, "
              f"{kinds['skip']} not files, {kinds['warn']} render with a warning), {args.views} views, "
              f"{args.workers} workers; {time.monotonic() - t0:.0f} s")
        print("\n| scenario | bad inputs tried | faults injected | objects lost | notes |\n|---|---|---|---|---|")
        for r in rows:
            print("| " + " | ".join(str(x) for x in r) + " |")
        print(f"\ntotals: bad inputs {sum(r[1] for r in rows)}, faults injected {sum(r[2] for r in rows)}, "
              f"objects lost {sum(r[3] for r in rows if isinstance(r[3], int))}, tracebacks seen {LOG.tracebacks}, "
              f"crashes (SIGSEGV/SIGABRT) {LOG.crashes}")
        print("\nfailure / skip / warning reasons (count, one example):")
        for kind, items in sorted(reasons.items(), key=lambda kv: -len(kv[1])):
            print(f"  {len(items):>4}  {items[0][:160]}")
    finally:
        if args.keep:
            print(f"work folder kept: {work}")
        else:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
