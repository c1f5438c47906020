"""Tests of mi_loop.io: mesh and image files, atomic writes, clear errors."""
from __future__ import annotations

import os

import numpy as np
import pytest
from matplotlib import image as mpl_image

from mi_loop import datasets, io

from helpers import exactly


@pytest.fixture
def blob():
    return datasets.blob()


def test_ply_round_trip_is_exact_and_keeps_order(tmp_path, blob):
    V, F = blob
    V = V[::-1].copy()                      # an order no loader would produce by itself
    F = (len(V) - 1) - F
    io.write_ply(tmp_path / "m.ply", V, F)
    V2, F2 = io.read_mesh(tmp_path / "m.ply")
    np.testing.assert_array_equal(V2, V)
    np.testing.assert_array_equal(F2, F)
    assert V2.dtype == np.float64 and F2.dtype == np.int64


def test_ply_stores_normals(tmp_path, blob):
    V, F = blob
    N = V / np.linalg.norm(V, axis=1, keepdims=True)
    io.write_ply(tmp_path / "n.ply", V, F, normals=N)
    data = (tmp_path / "n.ply").read_bytes()
    header, body = data.split(b"end_header\n", 1)
    assert b"property float nx" in header and f"element vertex {len(V)}".encode() in header
    vertices = np.frombuffer(body[: len(V) * 36],
                             dtype=[("p", "<f8", 3), ("n", "<f4", 3)])
    np.testing.assert_array_equal(vertices["p"], V)
    np.testing.assert_allclose(vertices["n"], N, rtol=1e-6)
    assert len(body) == len(V) * 36 + len(F) * 13


def test_ply_creases_round_trip(tmp_path, blob):
    """Crease edges and their sharpness (inf included) come back; the mesh itself is unchanged."""
    V, F = blob
    E = np.array([F[0, :2], F[3, 1:], F[7, [0, 2]]])
    io.write_ply(tmp_path / "c.ply", V, F, creases=(E, [2.5, np.inf, 0.25]))
    E2, s2 = io.read_creases(tmp_path / "c.ply")
    np.testing.assert_array_equal(E2, E)
    np.testing.assert_array_equal(s2, [2.5, np.inf, 0.25])
    V2, F2 = io.read_mesh(tmp_path / "c.ply")
    np.testing.assert_array_equal(V2, V)
    np.testing.assert_array_equal(F2, F)
    io.write_ply(tmp_path / "e.ply", V, F, creases=E[:1])          # edges only: infinitely sharp
    assert io.read_creases(tmp_path / "e.ply")[1].tolist() == [np.inf]
    io.write_ply(tmp_path / "p.ply", V, F)
    assert io.read_creases(tmp_path / "p.ply") is None


def test_write_ply_rejects_bad_creases(tmp_path, blob):
    V, F = blob
    with pytest.raises(ValueError, match=exactly(f"write_ply(): expected crease vertices in [0, {len(V)}), "
                                                 f"got crease 1 = [0, {len(V)}]")):
        io.write_ply(tmp_path / "x.ply", V, F, creases=np.array([[0, 1], [0, len(V)]]))
    with pytest.raises(ValueError, match=exactly("write_ply(): expected creases as (c, 2) integer vertex pairs with "
                                                 "one sharpness each, got int64 array of shape (2, 2) and 1 "
                                                 "sharpness values")):
        io.write_ply(tmp_path / "x.ply", V, F, creases=(np.array([[0, 1], [1, 2]]), [1.0]))
    assert not any(tmp_path.iterdir())


def test_obj_and_off_keep_vertex_order(tmp_path):
    V = np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0], [0, 0, 0]], dtype=float)
    F = np.array([[3, 2, 1], [3, 1, 0], [3, 0, 2], [0, 1, 2]])
    lines = [f"v {x} {y} {z}" for x, y, z in V] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in F]
    (tmp_path / "t.obj").write_text("\n".join(lines) + "\n")
    off = ["OFF", f"{len(V)} {len(F)} 0"] + [f"{x} {y} {z}" for x, y, z in V] + [f"3 {a} {b} {c}" for a, b, c in F]
    (tmp_path / "t.off").write_text("\n".join(off) + "\n")
    for name in ("t.obj", "t.off"):
        V2, F2 = io.read_mesh(tmp_path / name)
        np.testing.assert_array_equal(V2, V)
        np.testing.assert_array_equal(F2, F)


def test_write_replaces_atomically(tmp_path, blob, monkeypatch):
    V, F = blob
    target = tmp_path / "m.ply"
    io.write_ply(target, V, F)
    before = target.read_bytes()

    def fail(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(OSError, match="disk full"):
        io.write_ply(target, 2 * V, F)
    assert target.read_bytes() == before                 # old file intact
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.ply"]   # no temp file left


def test_overwrite_leaves_no_temporaries_and_keeps_permissions(tmp_path, blob):
    V, F = blob
    umask = os.umask(0o022)
    try:
        io.write_ply(tmp_path / "m.ply", V, F)
        assert (tmp_path / "m.ply").stat().st_mode & 0o777 == 0o644     # not mkstemp's 0600
        os.chmod(tmp_path / "m.ply", 0o640)
        io.write_ply(tmp_path / "m.ply", 2.0 * V, F)
    finally:
        os.umask(umask)
    assert (tmp_path / "m.ply").stat().st_mode & 0o777 == 0o640         # replaced file's mode kept
    np.testing.assert_array_equal(io.read_mesh(tmp_path / "m.ply")[0], 2.0 * V)
    assert [p.name for p in tmp_path.iterdir()] == ["m.ply"]


@pytest.mark.parametrize("name, content, message", [
    ("missing.ply", None, "expected an existing file, got '{path}': no such file"),
    ("mesh.stl", b"solid x\nendsolid x\n",
     "expected a .ply, .obj, .off, .glb, .gltf file, got '{path}' (suffix '.stl')"),
    ("empty.ply", b"", "expected a PLY file (a header from 'ply' to 'end_header') in '{path}', got an empty file"),
    ("garbage.ply", b"this is not a ply file\n",
     "expected a PLY file (a header from 'ply' to 'end_header') in '{path}', got a file starting b'this is not a pl'"),
    ("points.ply", (b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
                    b"property float z\nend_header\n0 0 0\n1 1 1\n"),
     "expected faces in '{path}', got 2 vertices and no faces (a point cloud?)"),
    ("empty.obj", b"# nothing\n", "expected vertices in '{path}', got none"),
])
def test_read_mesh_errors(tmp_path, name, content, message):
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(ValueError) as info:
        io.read_mesh(path)
    assert str(info.value) == "read_mesh(): " + message.format(path=path)


def test_write_ply_rejects_bad_arrays(tmp_path):
    V = np.zeros((3, 3))
    with pytest.raises(ValueError, match=exactly("write_ply(): expected face indices in [0, 3), "
                                                 "got face 1 = [0, 1, 3]")):
        io.write_ply(tmp_path / "x.ply", V, np.array([[0, 1, 2], [0, 1, 3]]))
    with pytest.raises(ValueError, match=exactly("write_ply(): expected V of shape (n, 3) with n > 0, "
                                                 "got shape (3, 2)")):
        io.write_ply(tmp_path / "x.ply", np.zeros((3, 2)), np.array([[0, 1, 2]]))
    with pytest.raises(ValueError, match=exactly("write_ply(): expected integer F of shape (m, 3), "
                                                 "got float64 array of shape (1, 3)")):
        io.write_ply(tmp_path / "x.ply", V, np.array([[0.0, 1, 2]]))
    with pytest.raises(ValueError, match=exactly("write_ply(): expected normals of shape (3, 3), got shape (2, 3)")):
        io.write_ply(tmp_path / "x.ply", V, np.array([[0, 1, 2]]), normals=np.zeros((2, 3)))
    assert not any(tmp_path.iterdir())


def test_png_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, size=(5, 7, 3), dtype=np.uint8)
    io.write_png(tmp_path / "a.png", image)
    read = np.round(mpl_image.imread(tmp_path / "a.png")[..., :3] * 255).astype(np.uint8)
    np.testing.assert_array_equal(read, image)
    io.write_png(tmp_path / "b.png", image / 255.0)
    read = np.round(mpl_image.imread(tmp_path / "b.png")[..., :3] * 255).astype(np.uint8)
    np.testing.assert_array_equal(read, image)


def test_png_errors(tmp_path):
    with pytest.raises(ValueError, match=exactly("write_png(): expected an (h, w, 3|4) image, got shape (4, 4)")):
        io.write_png(tmp_path / "a.png", np.zeros((4, 4)))
    image = np.zeros((4, 4, 3))
    image[2, 1, 0] = 1.5
    with pytest.raises(ValueError, match=exactly("write_png(): expected float pixels in [0, 1] (no NaN), "
                                                 "got 1.5 at pixel [2, 1]")):
        io.write_png(tmp_path / "a.png", image)
    with pytest.raises(ValueError, match=exactly("write_png(): expected float pixels in [0, 1] (no NaN), "
                                                 "got nan at pixel [0, 0]")):
        io.write_png(tmp_path / "a.png", np.full((4, 4, 3), np.nan))
    assert not any(tmp_path.iterdir())


def test_ensure_writable_dir(tmp_path):
    assert io.ensure_writable_dir(tmp_path / "a" / "b").is_dir()
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match=exactly(f"ensure_writable_dir(): expected a directory that files can be "
                                                 f"created in, got '{tmp_path / 'file' / 'sub'}': Not a directory")):
        io.ensure_writable_dir(tmp_path / "file" / "sub")
