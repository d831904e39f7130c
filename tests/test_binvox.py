"""binvox files built byte by byte from the format description (sc3d_data.io.binvox)."""
from __future__ import annotations

import numpy as np
import pytest

from sc3d_data.io.binvox import Binvox, binvox_bytes, read_binvox, write_binvox

# ShapeNetVox32-style header (as binvox writes it: 6 significant digits)
HEADER = b"#binvox 1\ndim 2 2 2\ntranslate -0.120158 -0.481158 -0.863158\nscale 7.24632\ndata\n"


def test_read_xzy_order_y_fastest(tmp_path):
    # 2^3 grid, file order index = x*4 + z*2 + y. Set file index 1 (x=0, z=0, y=1) and
    # file index 6 (x=1, z=1, y=0): runs 0x1, 1x1, 0x4, 1x1, 0x1
    p = tmp_path / "a.binvox"
    p.write_bytes(HEADER + bytes([0, 1, 1, 1, 0, 4, 1, 1, 0, 1]))
    g = read_binvox(p)
    assert g.voxels.shape == (2, 2, 2) and g.voxels.dtype == bool
    assert g.voxels.sum() == 2
    assert g.voxels[0, 1, 0]  # sc3d [x, y, z]
    assert g.voxels[1, 0, 1]
    assert g.translate == (-0.120158, -0.481158, -0.863158) and g.scale == 7.24632


def test_write_is_byte_exact_and_round_trips(tmp_path):
    p = tmp_path / "a.binvox"
    raw = HEADER + bytes([0, 1, 1, 1, 0, 4, 1, 1, 0, 1])
    p.write_bytes(raw)
    g = read_binvox(p)
    assert binvox_bytes(g) == raw  # a ShapeNetVox32-style file round-trips byte for byte
    q = tmp_path / "b.binvox"
    write_binvox(q, g.voxels, g.translate, g.scale)
    assert q.read_bytes() == raw


def test_long_runs_split_at_255_and_default_header(tmp_path):
    vox = np.zeros((8, 8, 8), bool)
    vox[7, 7, 7] = True  # last voxel in any order
    data = binvox_bytes(Binvox(vox))
    header = b"#binvox 1\ndim 8 8 8\ntranslate -0.5 -0.5 -0.5\nscale 1\ndata\n"
    assert data == header + bytes([0, 255, 0, 255, 0, 1, 1, 1])
    rng = np.random.default_rng(0)
    for res in (32, 64):
        v = rng.random((res,) * 3) < 0.3
        write_binvox(tmp_path / "r.binvox", v)
        back = read_binvox(tmp_path / "r.binvox")
        np.testing.assert_array_equal(back.voxels, v)
        assert back.translate == (-0.5, -0.5, -0.5) and back.scale == 1.0


def test_orientation_of_an_sc3d_grid_in_the_file(tmp_path):
    # a column along +y at x=0, z=1 of a 4^3 grid: y runs fastest in the file, so it is one
    # run of 4 ones starting at file index x*16 + z*4 = 4
    v = np.zeros((4, 4, 4), bool)
    v[0, :, 1] = True
    data = binvox_bytes(Binvox(v))
    assert data.endswith(bytes([0, 4, 1, 4, 0, 56]))


def test_bad_files_have_clear_errors(tmp_path):
    p = tmp_path / "bad.binvox"
    p.write_bytes(HEADER + bytes([0, 3]))
    with pytest.raises(ValueError, match="covers 3 voxels, the header says 8"):
        read_binvox(p)
    p.write_bytes(b"#notbinvox\n")
    with pytest.raises(ValueError, match="not a binvox file"):
        read_binvox(p)
    p.write_bytes(b"#binvox 1\ndim 2 2 3\ndata\n" + bytes([0, 12]))
    with pytest.raises(ValueError, match="cubic"):
        read_binvox(p)
