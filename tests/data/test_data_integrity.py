"""Cache file checks: whole files pass, truncated or wrong ones are named with a reason."""

import numpy as np
import trimesh
from PIL import Image

from ushape import atomic
from ushape.data import integrity


def test_ply_checks(tmp_path):
    path = tmp_path / "m.ply"
    data = trimesh.exchange.ply.export_ply(trimesh.creation.box(), encoding="binary")
    path.write_bytes(data)
    assert integrity.binary_ply_size(path) == len(data) and integrity.check_ply(path) is None
    path.write_bytes(data[:-5])
    assert integrity.check_ply(path) not in (None, integrity.MISSING)
    path.write_bytes(trimesh.exchange.ply.export_ply(trimesh.Trimesh(), encoding="binary"))
    assert integrity.check_ply(path) is not None
    assert integrity.check_ply(tmp_path / "none.ply") == integrity.MISSING


def test_npz_png_json_and_table_checks(tmp_path):
    npz = tmp_path / "a.npz"
    atomic.save_npz(npz, pos=np.zeros((5, 4), np.float32))
    assert integrity.check_npz(npz, {"pos": (None, 4)}, {"pos": "float32"}) is None
    assert "shape" in integrity.check_npz(npz, {"pos": (None, 3)})
    assert "dtype" in integrity.check_npz(npz, {"pos": (5, 4)}, {"pos": "float64"})
    assert "no array" in integrity.check_npz(npz, {"neg": (None, 4)})
    npz.write_bytes(npz.read_bytes()[:50])
    assert "unreadable" in integrity.check_npz(npz, {"pos": (None, 4)})
    png = tmp_path / "a.png"
    Image.fromarray(np.zeros((6, 8, 4), np.uint8)).save(png)
    assert integrity.check_png(png, (6, 8)) is None
    assert "expected RGBA 8x6" in integrity.check_png(png, (8, 6))
    png.write_bytes(png.read_bytes()[:30])
    assert "undecodable" in integrity.check_png(png, (6, 8))
    js = tmp_path / "a.json"
    js.write_text("[1, 2")
    assert "unparsable" in integrity.check_json(js)
    table = tmp_path / "t.txt"
    table.write_text("1 2 3 4 5\n6 7 8 9 10\n")
    assert integrity.check_text_rows(table, 2, 5) is None
    assert "expected 3 rows" in integrity.check_text_rows(table, 3, 5)
