"""Hostile files, round eleven: links planted where sc3d writes (the lock file, a temporary file,
a run's ``metrics.csv``, a prediction's outputs), shards whose data lives in other files (HDF5
external storage, external links, virtual datasets) or whose layout is not sc3d's, and two
``predict`` runs into one folder. Real commands, real HDF5; each victim file is checked
byte for byte."""
from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from sc3d_cli.data import main as data_main
from sc3d_cli.train import main as train_main
from conftest import REPO, SAMPLE_MESHES, one_error, run_cli
from test_faults import FAST

CHAIR_IMAGE = REPO / "assets" / "sample_images" / "chair.png"


def _victim(tmp_path: Path, name: str = "victim.txt") -> Path:
    victim = tmp_path / name
    victim.write_text("the user's own file\n")
    return victim


@pytest.fixture(scope="module")
def table_shards(tmp_path_factory) -> Path:
    """One mesh rendered (4 views) and voxelized: a small, real dataset to damage."""
    out = tmp_path_factory.mktemp("table") / "shards"
    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES / "table", "--out", out, "--voxelize", *FAST])
    return out


def _rerecorded(folder: Path) -> None:
    """Record the shards' new bytes and SHA-256 in the index, as someone crafting a dataset
    would (so that only the layout check can tell)."""
    index = json.loads((folder / "index.json").read_text())
    for entry in index["shards"]:
        data = (folder / entry["file"]).read_bytes()
        entry.update(bytes=len(data), sha256=hashlib.sha256(data).hexdigest())
    (folder / "index.json").write_text(json.dumps(index))


def test_a_lock_file_that_is_a_link_is_not_written_through(tmp_path):
    """A ``.sc3d.lock`` symlink in ``--out`` had its target truncated and overwritten with the
    PID of every command that locks the folder (render, merge, voxelize, fit, claims)."""
    victim = _victim(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    (out / ".sc3d.lock").symlink_to(victim)
    res = run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES / "table", "--out", out, *FAST], expect_exit=1)
    line = one_error(res.output)
    assert ".sc3d.lock: a symbolic link" in line and "remove it" in line, line
    assert victim.read_text() == "the user's own file\n"


def test_eval_does_not_write_through_a_link_at_its_temporary_name(trained_run, sample_shards, tmp_path):
    """``eval`` wrote ``metrics.json`` through a ``metrics.json.tmp`` symlink planted in its
    folder: the file it named was replaced and ``metrics.json`` became a link to it."""
    victim = _victim(tmp_path)
    out = tmp_path / "ev"
    out.mkdir()
    (out / "metrics.json.tmp").symlink_to(victim)
    run_cli(train_main, ["eval", "--checkpoint", trained_run / "checkpoints" / "last.pt", "--shards", sample_shards,
                         "--split", "train", "--pose", "head", "--out", out, "--examples", "0"])
    assert victim.read_text() == "the user's own file\n"
    assert not (out / "metrics.json").is_symlink() and "voxel_iou_0.4" in json.loads((out / "metrics.json").read_text())["mean"]


def test_fit_resume_refuses_a_metrics_log_that_is_a_link(trained_run, tmp_path):
    """``fit --resume`` rewrote, then appended to, the file a ``metrics.csv`` symlink in the run
    folder named (a new run already refused it)."""
    run = tmp_path / "run"
    shutil.copytree(trained_run, run)
    victim = _victim(tmp_path)
    (run / "metrics.csv").unlink()
    (run / "metrics.csv").symlink_to(victim)
    res = run_cli(train_main, ["fit", "--out", run, "--resume", "--steps", "400", "--no-progress"], expect_exit=1)
    line = one_error(res.output)
    assert "metrics.csv is a symbolic link" in line, line
    assert victim.read_text() == "the user's own file\n"


def test_predict_is_locked_and_replaces_its_files_without_following_links(trained_run, tmp_path):
    """Two ``predict`` runs into one folder were not locked (one left a ``.npz`` that did not
    load, another a ``.json`` of one checkpoint beside voxels of the other); and a prediction's
    ``.npz``, ``.obj`` and ``.png`` were written in place, through a link standing there."""
    from sc3d_data.io.outlock import exclusive_lock

    out = tmp_path / "pred"
    ckpt = trained_run / "checkpoints" / "last.pt"
    with exclusive_lock(out, "someone's predict", create=True):
        res = run_cli(train_main, ["predict", "--checkpoint", ckpt, CHAIR_IMAGE, "--out", out, "--pose", "head"],
                      expect_exit=1)
    line = one_error(res.output)
    assert "another process" in line and "someone's predict" in line, line
    assert not (out / "chair.npz").exists()

    run_cli(train_main, ["predict", "--checkpoint", ckpt, CHAIR_IMAGE, "--out", out, "--pose", "head"])
    victims = {}
    for ext in ("npz", "obj", "png"):
        victims[ext] = _victim(tmp_path, f"victim_{ext}.txt")
        (out / f"chair.{ext}").unlink()
        (out / f"chair.{ext}").symlink_to(victims[ext])
    run_cli(train_main, ["predict", "--checkpoint", ckpt, CHAIR_IMAGE, "--out", out, "--pose", "head"])
    for ext, victim in victims.items():
        assert victim.read_text() == "the user's own file\n", ext
        assert not (out / f"chair.{ext}").is_symlink(), ext
    assert np.load(out / "chair.npz")["voxels"].shape == (32, 32, 32)


def _assert_refused_by_readers(folder: Path, shard: Path, reason: str, tmp_path: Path) -> None:
    """``check``, ``preview`` and ``fit`` on ``folder`` each fail in one line naming ``shard`` (the
    data commands) and ``reason``."""
    for args in (["check", folder], ["preview", folder, "--out", tmp_path / "p.png"]):
        line = one_error(run_cli(data_main, args, expect_exit=1).output)
        assert str(shard) in line and reason in line, (args, line)
    res = run_cli(train_main, ["fit", "--shards", folder, "--out", tmp_path / "run", "--tiny", "--steps", "2",
                               "--batch-size", "2", "--no-progress"], expect_exit=1)
    assert reason in one_error(res.output)


def _external_images(shard: Path, outside: Path) -> None:
    with h5py.File(shard, "a") as f:
        shape = f["images"].shape
        del f["images"]
        outside.write_bytes(np.random.default_rng(0).integers(0, 255, int(np.prod(shape)), dtype=np.uint8).tobytes())
        f.create_dataset("images", shape=shape, dtype="uint8", external=[(str(outside), 0, int(np.prod(shape)))])


def _linked_images(shard: Path, outside: Path) -> None:
    with h5py.File(shard, "r") as src, h5py.File(outside, "w") as dst:
        dst.create_dataset("images", data=src["images"][()])
    with h5py.File(shard, "a") as f:
        del f["images"]
        f["images"] = h5py.ExternalLink(str(outside), "images")


def _virtual_images(shard: Path, outside: Path) -> None:
    with h5py.File(shard, "r") as src, h5py.File(outside, "w") as dst:
        dst.create_dataset("images", data=src["images"][()])
        shape = src["images"].shape
    layout = h5py.VirtualLayout(shape=shape, dtype="uint8")
    layout[...] = h5py.VirtualSource(str(outside), "images", shape=shape)
    with h5py.File(shard, "a") as f:
        del f["images"]
        f.create_virtual_dataset("images", layout)


@pytest.mark.parametrize("make,reason", [
    (_external_images, "'images' has external storage"),
    (_linked_images, "'images' is a ExternalLink, not data stored in the file"),
    (_virtual_images, "'images' is a virtual dataset"),
], ids=["external storage", "external link", "virtual dataset"])
def test_shards_whose_data_lives_in_other_files_are_refused(table_shards, tmp_path, make, reason):
    """A shard can take a dataset's values from any file on disk (raw bytes, another HDF5 file);
    ``info --verify`` passed such a shard (its SHA-256 recorded anew) and ``preview``, ``check``
    and ``fit`` read the outside file."""
    folder = tmp_path / "shards"
    shutil.copytree(table_shards, folder)
    make(folder / "shard-00000.h5", tmp_path / "outside.bin")
    _rerecorded(folder)
    shard = folder / "shard-00000.h5"
    report = run_cli(data_main, ["info", folder, "--verify"], expect_exit=1).output
    assert "BROKEN shards: 1 of 1" in report and f"{shard}: {reason}" in report, report
    _assert_refused_by_readers(folder, shard, reason, tmp_path)


def _replace(name, data=None, group=False):
    def damage(f: h5py.File) -> None:
        value = f[name][()] if data is None else data(f[name][()])
        del f[name]
        if group:
            f.create_group(name)
        else:
            f.create_dataset(name, data=value)
    return damage


@pytest.mark.parametrize("damage,reason", [
    (_replace("images", lambda a: a.astype(np.float64)), "'images' is float64, not uint8"),
    (_replace("images", lambda a: a[:, :3]), "'images' has shape [1, 3, 64, 64, 3], not [1, 4, 64, 64, 3]"),
    (_replace("images", lambda a: np.concatenate([a, a[..., :1]], axis=-1)), "'images' has shape [1, 4, 64, 64, 4]"),
    (_replace("images", lambda a: np.uint8(7)), "'images' has shape [], not [N, V, S, S, 3]"),
    (_replace("images", group=True), "'images' is a Group, not a dataset"),
    (_replace("R", lambda a: a[:, :, :2]), "'R' has shape [1, 4, 2, 3], not [1, 4, 3, 3]"),
    (_replace("masks", lambda a: np.concatenate([a, a])), "'masks' has shape [2, 4, 64, 64], not [1, 4, 64, 64]"),
    (_replace("split", lambda a: np.array([b"tr\xffin"], dtype=object)), "'split' holds a string that is not UTF-8"),
], ids=["float images", "fewer views", "4 channels", "scalar", "group", "R 2x3", "more rows", "split not UTF-8"])
def test_a_shard_of_another_layout_is_refused_in_one_line_naming_it(table_shards, tmp_path, damage, reason):
    """Shards whose arrays have another dtype, shape or kind than sc3d's layout gave tracebacks
    (``preview``: "Cannot handle this data type"; ``check``: IndexError; ``fit``: "The expanded
    size of the tensor"), blamed the output picture, or said nothing of the file."""
    folder = tmp_path / "shards"
    shutil.copytree(table_shards, folder)
    shard = folder / "shard-00000.h5"
    with h5py.File(shard, "a") as f:
        damage(f)
    _rerecorded(folder)
    _assert_refused_by_readers(folder, shard, reason, tmp_path)


def test_the_layout_check_passes_every_shard_sc3d_writes(sample_shards):
    """The check refuses nothing that ``render --voxelize`` wrote (11 objects, 24 views, voxels)."""
    from sc3d_data.io.shard_layout import layout_problem

    shards = sorted(sample_shards.glob("shard-*.h5"))
    assert shards
    for shard in shards:
        with h5py.File(shard, "r") as f:
            assert layout_problem(f) is None, shard
    assert os.path.exists(sample_shards / "index.json")


class _Payload:
    """A pickle that would create ``path`` when unpickled."""

    def __init__(self, path: Path):
        self.path = path

    def __reduce__(self):
        return (open, (str(self.path), "w"))


def test_resume_from_a_crafted_checkpoint_says_it_was_refused_not_missing(trained_run, tmp_path):
    """With a pickle payload as ``last.pt`` (and no other checkpoint), ``fit --resume`` refused
    it, as it must, but said "last.pt: checkpoint not found" of a file that is there."""
    import pickle

    run = tmp_path / "run"
    shutil.copytree(trained_run, run)
    for p in (run / "checkpoints").glob("*.pt"):
        p.unlink()
    (run / "checkpoints" / "last.pt").write_bytes(pickle.dumps(_Payload(tmp_path / "PWNED")))
    res = run_cli(train_main, ["fit", "--out", run, "--resume", "--no-progress"], expect_exit=1)
    line = one_error(res.output)
    assert f"no checkpoint of {run} can be resumed: {run / 'checkpoints' / 'last.pt'}" in line, line
    assert "not found" not in line
    assert not (tmp_path / "PWNED").exists()


def test_a_shard_with_fewer_objects_than_its_index_lists_is_refused(sample_shards, tmp_path):
    """A shard rewritten with its first 5 of 11 objects (every array cut alike, the index's
    SHA-256 recorded anew): ``fit`` trained on the 5 without a word ("no 'val' objects" where
    the index lists 2)."""
    folder = tmp_path / "shards"
    shutil.copytree(sample_shards, folder)
    index = json.loads((folder / "index.json").read_text())
    name = index["shards"][0]["file"]
    listed = sum(1 for o in index["objects"] if o["shard"] == name)
    with h5py.File(folder / name, "a") as f:
        for key in list(f):
            data = f[key][()][:5]
            del f[key]
            f.create_dataset(key, data=data, dtype=h5py.string_dtype("utf-8") if data.dtype.kind == "O" else None)
    _rerecorded(folder)
    res = run_cli(train_main, ["fit", "--shards", folder, "--out", tmp_path / "run", "--tiny", "--steps", "2",
                               "--batch-size", "2", "--no-progress"], expect_exit=1)
    line = one_error(res.output)
    assert f"{folder / name}: holds 5 objects, {folder}/index.json lists {listed} in it" in line, line


def test_pictures_replace_a_link_at_their_name_instead_of_writing_through_it(table_shards, tmp_path):
    """``check``'s worst views, ``preview``'s sheet and ``fit``'s curves were saved in place: a
    link standing at the name had the file it named overwritten with the picture."""
    from PIL import Image

    folder = tmp_path / "shards"
    shutil.copytree(table_shards, folder)
    pictures = {"check": folder / "check_worst.png", "preview": tmp_path / "sheet.png",
                "fit": tmp_path / "run" / "curves.png"}
    pictures["fit"].parent.mkdir()
    victims = {}
    for what, picture in pictures.items():
        victims[what] = _victim(tmp_path, f"victim_{what}.txt")
        picture.symlink_to(victims[what])
    run_cli(data_main, ["check", folder, "--png", pictures["check"]])
    run_cli(data_main, ["preview", folder, "--out", pictures["preview"]])
    res = run_cli(train_main, ["fit", "--shards", folder, "--out", tmp_path / "run", "--tiny", "--steps", "2",
                               "--batch-size", "2", "--val-every", "0", "--no-progress"], expect_exit=1)
    assert "curves.png is a symbolic link" in one_error(res.output)  # a run's own file: refused (above)
    pictures["fit"].unlink()
    run_cli(train_main, ["fit", "--shards", folder, "--out", tmp_path / "run", "--tiny", "--steps", "2",
                         "--batch-size", "2", "--val-every", "0", "--no-progress"])
    for what, picture in pictures.items():
        assert victims[what].read_text() == "the user's own file\n", what
        assert not picture.is_symlink() and Image.open(picture).format == "PNG", what
