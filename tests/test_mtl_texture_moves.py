"""An MTL ``map_Kd`` moved by ``-o u v w`` (offset) and ``-s u v w`` (scale) is drawn moved: a
texture coordinate ``uv`` reads the texture at ``scale * uv + offset``, as Blender's OBJ importer
(Mapping node: Location, Scale) and three.js's MTLLoader (``offset``, ``repeat``) read it. Before,
it was drawn unmoved with a warning.

Every cube has all its texture coordinates at one point of a 4 x 4 texture of 16 colours (each
texel its own colour), so the colour drawn names the texel read. The reference of each moved
cube is the same cube, unmoved, with its texture coordinates written at the point the move
gives by hand. The other conventions (offset then scale, or the inverse move) read other texels."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from sc3d_cli.data import main as data_main
from conftest import objects_by_id, run_cli
from test_faults import CUBE_F, CUBE_V, FAST, index_of

START = (0.125, 0.125)  # the middle of texel (column 0, row 0 from the bottom)
CASES = {  # name: (map_Kd options, the texture coordinate they make of START, by hand)
    "offset": ("-o 0.25 0.5 0", (0.375, 0.625)),
    "offset_u_only": ("-o 0.25", (0.375, 0.125)),
    "scale": ("-s 3 3 1", (0.375, 0.375)),
    "scale_and_offset": ("-s 3 1 1 -o 0.25 0 0", (0.625, 0.125)),
    "offset_and_scale_written_the_other_way": ("-o 0.25 0 0 -s 3 1 1", (0.625, 0.125)),
    "wrapping_past_1": ("-o 1.5 -0.5", (0.625, 0.625)),
    "no_move": ("-s 1 1 1 -o 0 0 0", START),
}
#: where the wrong conventions would read START with the "scale_and_offset" options: (uv + o) * s
#: and (uv - o) / s; each is another texel than the one by hand
WRONG = {"offset then scale": (0.125, 0.125), "inverse": (0.9583, 0.125)}


def _cube(folder: Path, options: str, uv: tuple[float, float]) -> None:
    """A textured cube in ``folder`` (m.obj, m.mtl, t.png): every corner's ``vt`` at ``uv``, the
    material's ``map_Kd`` with ``options``."""
    from PIL import Image

    folder.mkdir(parents=True)
    lines = ["mtllib m.mtl", "usemtl mat"] + ["v %g %g %g" % tuple(v) for v in CUBE_V]
    lines += ["vt %r %r" % uv, *("f %d/1 %d/1 %d/1" % tuple(np.add(f, 1)) for f in CUBE_F)]
    (folder / "m.obj").write_text("\n".join(lines) + "\n")
    (folder / "m.mtl").write_text(f"newmtl mat\nKd 1 1 1\nmap_Kd {options} t.png\n".replace("  ", " "))
    # 16 colours that are no blend of each other's neighbours (a linear ramp would make the blend
    # of texels 3 and 0 that a coordinate near 1 reads equal texel 2); image row 0 is v 0.75-1
    texels = np.random.default_rng(7).integers(20, 236, (4, 4, 3)).astype(np.uint8)
    Image.fromarray(texels).save(folder / "t.png")


def _render(tmp_path: Path, cubes: dict[str, tuple[str, tuple[float, float]]]) -> dict[str, np.ndarray]:
    meshes = tmp_path / "m" / "c"
    for name, (options, uv) in cubes.items():
        _cube(meshes / name, options, uv)
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    index = index_of(out)
    assert index["failures"] == [] and index["warnings"] == []
    return {key[1].split("/")[0]: obj["images"] for key, obj in objects_by_id(out).items()}


def test_a_moved_texture_is_read_where_its_options_move_it(tmp_path):
    cubes = {name: (options, START) for name, (options, _) in CASES.items()}
    cubes |= {f"ref_{name}": ("", uv) for name, (_, uv) in CASES.items()}
    cubes |= {f"wrong_{k}": ("", uv) for k, uv in enumerate(WRONG.values())}
    images = _render(tmp_path, cubes)
    for name in CASES:
        np.testing.assert_array_equal(images[name], images[f"ref_{name}"], err_msg=name)
    for k in range(len(WRONG)):  # the other conventions draw other colours
        assert not np.array_equal(images["scale_and_offset"], images[f"wrong_{k}"])
    assert not np.array_equal(images["scale"], images["no_move"])
