"""``--outside-textures refuse`` fails an object whose material or texture file lies outside
``--meshes`` (``../`` leaving it), judged from the path alone (docs/data.md, ``render --help``).
Since the stand-ins of b5520d6 (``io.stand_ins``), such a name with a file of its bare name beside
the file naming it was read from there instead, the object rendered, exit 0, and the warning
said the file outside was "not found" (it may well be there; it is not read). The stand-in is
still what ``warn`` draws; ``refuse`` refuses as before b5520d6 (review28). Loader only."""
from __future__ import annotations

from pathlib import Path

import pytest
from PIL import Image

CUBE = ("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nusemtl red\n"
        "f 1/1 2/2 3/3\nf 1/1 3/3 4/4\n")


def _dataset(tmp_path: Path, mtllib: str, map_kd: str) -> Path:
    """``tmp_path/ds/thing/m.obj`` with ``m.mtl`` and ``t.png`` beside it, and ``m.mtl`` and
    ``t.png`` (another colour) in ``tmp_path/outside``; the OBJ names ``mtllib``, the MTL ``map_Kd``."""
    folder, outside = tmp_path / "ds" / "thing", tmp_path / "outside"
    for d, colour in ((folder, (200, 30, 30)), (outside, (0, 200, 0))):
        d.mkdir(parents=True)
        (d / "m.mtl").write_text(f"newmtl red\nKd 1 1 1\nmap_Kd {map_kd}\n")
        Image.new("RGB", (8, 8), colour).save(d / "t.png")
    (folder / "m.obj").write_text(f"mtllib {mtllib}\n{CUBE}")
    return folder / "m.obj"


@pytest.mark.parametrize("mtllib, map_kd, outside_file", [
    ("m.mtl", "../../outside/t.png", "outside/t.png"),
    ("../../outside/m.mtl", "t.png", "outside/m.mtl")])
def test_a_file_outside_the_dataset_folder_is_refused_though_one_of_its_name_lies_beside(
        tmp_path, mtllib, map_kd, outside_file):
    from sc3d_data.io.meshes import MeshError, load_mesh

    path = _dataset(tmp_path, mtllib, map_kd)
    with pytest.raises(MeshError, match=f"{tmp_path / outside_file} lies outside the dataset folder "
                                        f".*refused by --outside-textures refuse"):
        load_mesh(path, root=tmp_path / "ds", outside_textures="refuse")
    scene, _, _, warnings = load_mesh(path, root=tmp_path / "ds", outside_textures="warn")
    (geometry,) = scene.geometry.values()
    assert geometry.visual.material.image.convert("RGB").getpixel((0, 0)) == (200, 30, 30)  # the one beside
    name = f"texture {map_kd} (from m.mtl)" if outside_file.endswith(".png") else f"material file {mtllib}"
    assert warnings == [f"{path}: {name} lies outside the dataset folder, not read; {Path(outside_file).name} "
                        f"beside {'m.mtl' if outside_file.endswith('.png') else 'the OBJ'} is read in its place"]
