"""Data-half defects of the twenty-sixth round (items of the last left-alone lists). Real renderer,
real files written here; expected messages and values derived by hand."""
from __future__ import annotations

from sc3d_cli.data import main as data_main
from conftest import run_cli
from test_faults import FAST, index_of


def test_a_mesh_of_collinear_triangles_is_named_so(tmp_path):
    """PyTorch3D's ``model2.obj``: four points on one line, two triangles whose cross products are
    not exactly zero in float64 (rounding), so they pass the exact area test and the render's
    silhouette is empty; the failure blamed "an outlier vertex far from the rest". It must say that
    the triangles' corners lie on one line. The control, two tiny triangles 10^6 apart (an outlier
    indeed), keeps the outlier message."""
    meshes = tmp_path / "m" / "c"
    meshes.mkdir(parents=True)
    (meshes / "needles.obj").write_text("v 0.1 0.2 0.3\nv 0.2 0.3 0.4\nv 0.3 0.4 0.5\nv 0.4 0.5 0.6\n"
                                        "f 1 2 3\nf 1 2 4\nf 1 1 2\n")  # and one of two corners in one point
    (meshes / "outlier.obj").write_text("v 0 0 0\nv 1e-4 0 0\nv 0 1e-4 0\nv 1e6 0 0\nv 1e6 1e-4 0\nv 1e6 0 1e-4\n"
                                        "f 1 2 3\nf 4 5 6\n")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST], expect_exit=1)
    reasons = {f["source"]: f["reason"] for f in index_of(out)["failures"]}
    assert reasons == {
        str(meshes / "needles.obj"): f"{meshes / 'needles.obj'}: every triangle of it has its corners on one line "
                                     "(but for rounding), so it has no surface to draw",
        str(meshes / "outlier.obj"): f"{meshes / 'outlier.obj'}: the silhouette is empty in every view after "
                                     "normalisation (geometry collapsed to under a pixel, e.g. by an outlier vertex "
                                     "far from the rest)"}, reasons


def test_the_colours_of_an_off_file_that_are_dropped_are_warned_of(tmp_path):
    """trimesh's OFF reader drops ``COFF`` vertex colours and the colours after a face's corners:
    such a tetrahedron rendered grey with no warning (docs/data.md said so). Each must now warn
    that its colours are not read; the same tetrahedron without colours, also with a comment
    after its last face, warns of nothing (control)."""
    meshes = tmp_path / "m" / "c"
    meshes.mkdir(parents=True)
    vertices, faces = ["0 0 0", "1 0 0", "0 1 0", "0 0 1"], ["3 0 1 2", "3 0 1 3", "3 0 2 3", "3 1 2 3"]
    colours = ["255 0 0", "0 255 0", "0 0 255", "255 255 0"]
    files = {"vertex_colours": ["COFF", "4 4 0", *(f"{v} {c} 255" for v, c in zip(vertices, colours)), *faces],
             "face_colours": ["OFF", "4 4 0", *vertices, *(f"{f} 1 0 0" for f in faces)],
             "plain": ["OFF", "4 4 0", *vertices, *faces],
             "comment": ["OFF", "4 4 0", *vertices, *faces[:-1], faces[-1] + "  # the last face", ""]}
    for name, lines in files.items():
        (meshes / f"{name}.off").write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert sorted(w["warning"] for w in index_of(out)["warnings"]) == [
        f"{meshes / 'face_colours.off'}: its per-face colours are not read: it renders in the default grey",
        f"{meshes / 'vertex_colours.off'}: its vertex colours (COFF) are not read: it renders in the default grey"]
