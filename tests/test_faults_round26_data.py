"""Data-half defects of the twenty-sixth round (items of the last left-alone lists). Real renderer,
real files written here; expected messages and values derived by hand."""
from __future__ import annotations

import numpy as np

from sc3d_cli.data import main as data_main
from conftest import objects_by_id, run_cli
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


def _ply_tetrahedron(vertex_colours: list | None = None, face_colours: list | None = None) -> str:
    """The tetrahedron of the OFF test below as an ASCII PLY, with colours (bytes) by vertex or face."""
    def props(colours):
        return ["property uchar red", "property uchar green", "property uchar blue"] if colours else []

    head = ["ply", "format ascii 1.0", "element vertex 4", "property float x", "property float y", "property float z",
            *props(vertex_colours), "element face 4", "property list uchar int vertex_indices", *props(face_colours),
            "end_header"]
    rows = [v + ("" if not vertex_colours else " %d %d %d" % c) for v, c in zip(TETRA_V, vertex_colours or TETRA_V)]
    rows += [f + ("" if not face_colours else " %d %d %d" % c) for f, c in zip(TETRA_F, face_colours or TETRA_F)]
    return "\n".join(head + rows) + "\n"


TETRA_V = ["0 0 0", "1 0 0", "0 1 0", "0 0 1"]
TETRA_F = ["3 0 1 2", "3 0 1 3", "3 0 2 3", "3 1 2 3"]


def test_the_colours_of_an_off_file_are_drawn(tmp_path):
    """trimesh's OFF reader drops ``COFF`` vertex colours and the colours after a face's corners:
    such a tetrahedron rendered grey (a warning said so since the twenty-sixth round). They must
    be drawn as the same tetrahedron written by hand as a PLY with those colours draws them:
    MeshLab's whole numbers with alpha, Geomview's floats 0-1, whole numbers none above 1 read as
    floats (``1 0 0`` is red: the control that the 0-255 reading, which draws it black, is not
    taken there), per-face colours in both, and faces without a colour beside coloured ones in
    the renderer's grey 0.3 (77 of 255; the uncoloured file draws within one level of a PLY of
    that colour). A face colour of one number (an index into Geomview's colour map) is not read:
    warned of, drawn as the file without colours."""
    meshes = tmp_path / "m" / "c"
    meshes.mkdir(parents=True)
    colours = [(200, 30, 60), (20, 180, 90), (40, 60, 230), (250, 240, 10)]
    units = [(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0)]
    floats = [" ".join(f"{c / 255:.6f}" for c in rgb) for rgb in colours]
    files = {"vc_int": ["COFF", "4 4 0", *(f"{v} {' '.join(map(str, c))} 255" for v, c in zip(TETRA_V, colours)),
                        *TETRA_F],
             "vc_float": ["COFF", "4 4 0", *(f"{v} {c} 1.0" for v, c in zip(TETRA_V, floats)), *TETRA_F],
             "vc_unit_ints": ["COFF", "4 4 0", *(f"{v} {' '.join(map(str, c))} 1" for v, c in zip(TETRA_V, units)),
                              *TETRA_F],
             "fc_int": ["OFF", "4 4 0", *TETRA_V, *(f"{f} {' '.join(map(str, c))}" for f, c in zip(TETRA_F, colours))],
             "fc_float": ["OFF", "4 4 0", *TETRA_V, *(f"{f} {c} 1" for f, c in zip(TETRA_F, floats))],
             "fc_partial": ["OFF", "4 4 0", *TETRA_V, TETRA_F[0] + " 0 0 255", TETRA_F[1] + " 0 0 255", *TETRA_F[2:]],
             "fc_colour_map": ["OFF", "4 4 0", *TETRA_V, *(f + " 7" for f in TETRA_F)],
             "plain": ["OFF", "4 4 0", *TETRA_V, *TETRA_F]}
    for name, lines in files.items():
        (meshes / f"{name}.off").write_text("\n".join(lines) + "\n")
    grey = (77, 77, 77)
    references = {"ref_vertex": _ply_tetrahedron(vertex_colours=colours),
                  "ref_unit": _ply_tetrahedron(vertex_colours=[tuple(255 * c for c in u) for u in units]),
                  "ref_face": _ply_tetrahedron(face_colours=colours),
                  "ref_partial": _ply_tetrahedron(face_colours=[(0, 0, 255), (0, 0, 255), grey, grey]),
                  "ref_grey": _ply_tetrahedron(face_colours=[grey] * 4)}
    for name, text in references.items():
        (meshes / f"{name}.ply").write_text(text)
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert [w["warning"] for w in index_of(out)["warnings"]] == [
        f"{meshes / 'fc_colour_map.off'}: its per-face colours are not read: it renders in the default grey"]
    objects = {name[1]: obj for name, obj in objects_by_id(out).items()}
    reference = objects["ref_vertex"]["images"][objects["ref_vertex"]["masks"] > 0].astype(int)
    assert np.ptp(reference, axis=1).max() > 100  # the reference is coloured
    for name, ref in (("vc_int", "ref_vertex"), ("vc_float", "ref_vertex"), ("vc_unit_ints", "ref_unit"),
                      ("fc_int", "ref_face"), ("fc_float", "ref_face"), ("fc_partial", "ref_partial"),
                      ("fc_colour_map", "plain")):
        np.testing.assert_array_equal(objects[name]["masks"], objects[ref]["masks"], err_msg=name)
        np.testing.assert_array_equal(objects[name]["images"], objects[ref]["images"], err_msg=name)
    assert np.abs(objects["plain"]["images"].astype(int) - objects["ref_grey"]["images"]).max() <= 1
