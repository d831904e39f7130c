"""Training-half defects of the twenty-fourth round (items of the last left-alone list and the
twenty-fourth attack); expected values are derived by hand, never from the code under test."""
from __future__ import annotations

import numpy as np

from sc3d_cli.train import main as train_main
from conftest import run_cli
from test_faults_train import tiny_run  # noqa: F401 - a fixture
from test_faults_train_round8 import CHAIR


def test_the_predicted_mesh_stays_inside_the_grid_at_low_thresholds():
    """``predict``'s mesh is marching cubes of the zero-padded probabilities; at a threshold below
    half a border voxel's probability the surface crossed between that voxel's centre and the
    padding's, outside the grid's cube [-0.5, 0.5]^3 which the documentation promises (at
    ``--threshold 0`` on the padding itself, half a voxel out). By hand, an 8^3 grid (voxel
    centres at -0.5 + (i + 0.5)/8) with a 3^3 block of probability 1 in its low corner:

    - threshold 0.1: the inner faces cross 0.9 of the way from the centre of voxel 2 (-0.1875)
      to that of voxel 3 (-0.0625), at -0.075; the outer faces end on the cube's faces, -0.5;
    - threshold 0.5 (the control, unchanged): the inner faces half-way, -0.125; outer -0.5;
    - threshold 0 of probabilities all above 0: every voxel is occupied, so the surface is the
      cube's, from -0.5 to 0.5 on every axis.
    """
    from sc3d_train.evaluation.predict import voxel_mesh

    block = np.zeros((8, 8, 8), dtype=np.float32)
    block[:3, :3, :3] = 1.0
    for threshold, inner in ((0.1, -0.075), (0.5, -0.125)):
        verts, faces = voxel_mesh(block, threshold)
        assert len(faces) > 0
        np.testing.assert_allclose(verts.min(axis=0), [-0.5] * 3, atol=1e-6, err_msg=str(threshold))
        np.testing.assert_allclose(verts.max(axis=0), [inner] * 3, atol=1e-6, err_msg=str(threshold))
    everywhere = np.random.default_rng(0).uniform(0.01, 1.0, (8, 8, 8)).astype(np.float32)
    verts, faces = voxel_mesh(everywhere, 0.0)
    assert len(faces) > 0
    np.testing.assert_allclose(verts.min(axis=0), [-0.5] * 3, atol=1e-6)
    np.testing.assert_allclose(verts.max(axis=0), [0.5] * 3, atol=1e-6)


# ----------------------------------------------------------------------------- the twenty-fourth attack
def test_a_camera_jpeg_with_a_preview_image_is_predicted_as_its_photo_and_names_print_on_one_line(
        sample_shards, tiny_run, tmp_path):
    """A JPEG that carries a second image (MPO: a phone's preview, a stereo camera's other eye) was
    refused as "an animated image of 2 frames"; viewers show its first image, which is an
    ordinary JPEG. It must predict what the same pixels saved as a plain JPEG (the reference)
    predict. An image named with a newline was printed raw, splitting its result line (and its
    mode error): each must be one line naming it as ``\\n``."""
    import json

    import h5py
    from PIL import Image

    with h5py.File(next(sample_shards.glob("*.h5")), "r") as f:
        view = Image.fromarray(f["images"][0, 3])
    view.save(tmp_path / "plain.jpg")
    view.save(tmp_path / "photo.jpg", format="MPO", save_all=True, append_images=[view.resize((32, 32))])
    assert Image.open(tmp_path / "photo.jpg").n_frames == 2  # the file holds two images
    named = tmp_path / "two\nlines.jpg"
    view.save(named)
    out = tmp_path / "pred"
    res = run_cli(train_main, ["predict", "--checkpoint", tiny_run, tmp_path / "plain.jpg", tmp_path / "photo.jpg",
                               named, "--out", out, "--device", "cpu"])
    plain, photo = (json.loads((out / f"{n}.json").read_text()) for n in ("plain", "photo"))
    assert photo["azimuth_deg"] == plain["azimuth_deg"] and photo["occupied_voxels"] == plain["occupied_voxels"]
    lines = res.output.splitlines()
    assert len(lines) == 3 and lines[2].startswith(f"{tmp_path}/two\\nlines.jpg: azimuth "), res.output
    view.convert("CMYK").save(tmp_path / "cmyk\nname.jpg")
    res = run_cli(train_main, ["predict", "--checkpoint", tiny_run, tmp_path / "cmyk\nname.jpg", "--out",
                               tmp_path / "pred2", "--device", "cpu"], expect_exit=1)
    assert res.output.count("\n") == 1 and "cmyk\\nname.jpg: image mode 'CMYK' not supported" in res.output


def test_a_checkpoint_cut_short_is_named_so(tiny_run, tmp_path):
    """A checkpoint whose write or copy did not finish failed "not a readable checkpoint (OSError:
    [Errno 22] Invalid argument)" or with torch's message cut mid-sentence. A real checkpoint cut
    at a quarter, half and 99% of its bytes must be refused saying it was cut short."""
    data = (tiny_run / "checkpoints" / "last.pt").read_bytes()
    for share in (0.25, 0.5, 0.99):
        cut = tmp_path / f"cut{share}.pt"
        cut.write_bytes(data[:int(len(data) * share)])
        res = run_cli(train_main, ["predict", "--checkpoint", cut, CHAIR, "--out", tmp_path / "p", "--device", "cpu"],
                      expect_exit=1)
        assert f"{cut}: a checkpoint cut short or damaged (its zip archive has no end" in res.output, res.output


def test_claims_replaces_links_at_its_report_names_and_runs_a_run_named_twice_once(sample_shards, tmp_path):
    """``claims`` wrote claims.md and claims.json with a plain write: a symlink (or hard link) at
    those names had the file it points to overwritten by the report, as no other command does
    (fit refuses links, eval replaces its files). The user's files must keep their text and the
    report be written in their place. ``--runs sup-3tube,sup-3tube`` trained the run, then said
    of the second mention "done before": a run named twice is one run."""
    import os

    from sc3d_train.evaluation.claims import ClaimsPreset, run_all

    out = tmp_path / "claims"
    out.mkdir()
    notes, mine = tmp_path / "notes.md", tmp_path / "mine.json"
    notes.write_text("my notes\n")
    mine.write_text('{"mine": 1}\n')
    (out / "claims.md").symlink_to(notes)
    os.link(mine, out / "claims.json")
    said = []
    preset = ClaimsPreset(steps=2, batch_size=4, lr=1e-3, tiny=True, extra={"val_every": 0})
    run_all(sample_shards, sample_shards, out, preset, eval_split="test", device="cpu",
            runs=["sup-3tube", "sup-3tube"], echo=said.append)
    assert notes.read_text() == "my notes\n" and mine.read_text() == '{"mine": 1}\n'
    assert not (out / "claims.md").is_symlink() and "Ours (Sup), 3 tubes" in (out / "claims.md").read_text()
    assert '"results"' in (out / "claims.json").read_text()
    assert not any("done before" in line for line in said), said
