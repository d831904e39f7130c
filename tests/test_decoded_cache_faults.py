"""The decoded cache (``fit --decoded-cache``) under faults a user meets: a full disk while it is
built, a shard replaced behind its index's back, a cache file cut short while a run has it
mapped. Each is one line naming the folder or file, or the right data; never a SIGBUS or stale
pixels. Built in subprocesses where the failure before the fix was a SIGBUS (it would kill pytest)."""
from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from sc3d_data.io.shards import load_index, shard_path


def _python(code: str, *args: str, wrap: list[str] | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([*(wrap or []), sys.executable, "-c", code, *args], capture_output=True, text=True,
                          timeout=120)


BUILD = """
import sys
from pathlib import Path
from sc3d_data.io.shards import ShardError, load_index, shard_path
from sc3d_train.data.decoded_cache import DecodedCache
data, cache = Path(sys.argv[1]), Path(sys.argv[2])
paths = [str(shard_path(data, e["file"])) for e in load_index(data)["shards"]]
try:
    DecodedCache(cache, data, paths, 48, True)
except ShardError as e:
    print("ERROR", e)
"""


def test_a_full_disk_while_building_is_one_line_and_leaves_no_partial_entry(sample_shards, tmp_path):
    """A cache folder on a disk too small for the copy (a 1 MiB tmpfs, mounted in a user
    namespace) stops with one line naming the folder; stores into a memory map of a sparse file
    killed the process with SIGBUS instead, and left the partial copy filling the disk."""
    small = tmp_path / "small"
    small.mkdir()
    mount = f"mount -t tmpfs -o size=1m tmpfs {small} && \"$@\"; echo rc=$?; ls -A {small}/cache"
    wrap = ["unshare", "--user", "--map-root-user", "--mount", "sh", "-c", mount, "sh"]
    probe = wrap[:6] + [f"mount -t tmpfs tmpfs {small}"]
    if shutil.which("unshare") is None or subprocess.run(probe, capture_output=True).returncode != 0:
        pytest.skip("no user namespaces to mount a small tmpfs in")
    got = _python(BUILD, str(sample_shards), str(small / "cache"), wrap=wrap)
    lines = got.stdout.splitlines()
    assert lines[-2:] == ["rc=0", load_index(sample_shards)["shards"][0]["sha256"] + ".lock"], (lines, got.stderr)
    assert lines[0].startswith(f"ERROR {small / 'cache'}: cannot write the decoded cache") and "space" in lines[0]


def test_a_shard_replaced_behind_its_index_is_not_served_stale(sample_shards, tmp_path):
    """A shard file replaced without its index (restored from a backup, copied from another
    render, a voxelize killed before it wrote the index) is what reading the shards gives; the
    cache, keyed by the index's SHA-256, served the old pixels with exit 0."""
    from sc3d_train.data.dataset import ShardDataset

    data = tmp_path / "data"
    shutil.copytree(sample_shards, data)
    cache = tmp_path / "cache"
    ShardDataset(data, "train", decoded_cache=cache).close()
    name = load_index(data)["shards"][0]["file"]
    with h5py.File(data / name, "r+") as f:  # the index is left as it was
        f["images"][...] = 255 - f["images"][...]
    plain, cached = ShardDataset(data, "train"), ShardDataset(data, "train", decoded_cache=cache)
    every = list(range(len(plain)))
    a, b = plain.compact_batch(every)[0], cached.compact_batch(every)[0]
    for k in ("images", "masks", "masks_sc", "voxels"):
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    plain.close()
    cached.close()
    again = ShardDataset(data, "train", decoded_cache=cache)  # known now: served without hashing
    np.testing.assert_array_equal(again.compact_batch(every)[0]["images"], a["images"])


CUT = """
import os, sys
import numpy as np
from pathlib import Path
from sc3d_data.io.shards import ShardError, load_index, shard_path
from sc3d_train.data.decoded_cache import DecodedCache
data, cache = Path(sys.argv[1]), Path(sys.argv[2])
paths = [str(shard_path(data, load_index(data)["shards"][0]["file"]))]
c = DecodedCache(cache, data, paths, 48, True)
one = np.zeros(1, dtype=int)
c.views(one, one, one)
images = c.folders[0] / "images.npy"
os.truncate(images, 1000)
try:
    c.views(one, one + 5, one)
except ShardError as e:
    print("ERROR", e)
"""


def test_a_cache_file_cut_short_while_mapped_is_one_line(sample_shards, tmp_path):
    """docs/training.md: "a file cut short while a run has it open fails in one line naming it";
    a batch read from the mapped pages past the new end was a SIGBUS."""
    got = _python(CUT, str(sample_shards), str(tmp_path / "cache"))
    assert got.returncode == 0, (got.returncode, got.stderr[-2000:])
    images = tmp_path / "cache" / load_index(sample_shards)["shards"][0]["sha256"] / "images.npy"
    assert got.stdout.startswith(f"ERROR {images}: cut short"), got.stdout
