"""Reading oriented points (mi_loop.io.points): formats, mesh sampling, errors.

Normal estimation (mi_loop.mesh.points) is tested in tests/mesh/test_points.py.
"""
from __future__ import annotations

import numpy as np
import pytest

from mi_loop.io.points import load_oriented_points

from helpers import DATA, sphere_points, value_error

BUNNY_SCAN = DATA / "scans" / "bunny_rangescans_merged_stride3.ply"


def _write_ply_points(path, P, N=None, binary=False):
    props = ["x", "y", "z"] + (["nx", "ny", "nz"] if N is not None else [])
    A = P if N is None else np.hstack([P, N])
    fmt = "binary_little_endian" if binary else "ascii"
    head = (f"ply\nformat {fmt} 1.0\nelement vertex {len(A)}\n"
            + "".join(f"property float {p}\n" for p in props) + "end_header\n")
    with open(path, "wb") as fh:
        fh.write(head.encode())
        if binary:
            fh.write(A.astype("<f4").tobytes())
        else:
            fh.write("".join(" ".join(f"{x:.9g}" for x in row) + "\n" for row in A).encode())


def _cube():
    V = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    F = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return V, F


def _check_cube_samples(P, N):
    """Samples lie on the unit cube's faces; normals are the outward axis directions there."""
    on = np.isclose(P, 0, atol=1e-6) | np.isclose(P, 1, atol=1e-6)
    assert on.any(1).all() and (P > -1e-9).all() and (P < 1 + 1e-9).all()
    np.testing.assert_allclose(np.abs(N).max(1), 1.0, atol=1e-9)
    axis = np.argmax(np.abs(N), 1)
    coord = P[np.arange(len(P)), axis]
    expected = np.where(N[np.arange(len(P)), axis] > 0, 1.0, 0.0)
    np.testing.assert_allclose(coord, expected, atol=1e-6)


@pytest.mark.parametrize("binary", [False, True])
def test_ply_points_with_and_without_normals(tmp_path, binary):
    P = sphere_points(200)[0]
    _write_ply_points(tmp_path / "n.ply", P, 2 * P, binary)   # normals get unit length
    Q, N, info = load_oriented_points(tmp_path / "n.ply")
    np.testing.assert_allclose(Q, P, atol=1e-6)
    np.testing.assert_allclose(N, P, atol=1e-6)
    assert info["kind"] == "points" and info["has_normals"] and info["n_points"] == 200
    _write_ply_points(tmp_path / "p.ply", P, None, binary)
    Q, N, info = load_oriented_points(tmp_path / "p.ply")
    assert N is None and not info["has_normals"] and Q.shape == (200, 3)


def test_text_formats_with_comments_and_headers(tmp_path):
    P = sphere_points(50)[0]
    rows6 = "\n".join(" ".join(f"{x:.12g}" for x in r) for r in np.hstack([P, P]))
    rows3 = "\n".join(",".join(f"{x:.12g}" for x in r) for r in P)
    (tmp_path / "a.xyz").write_text("# comment\n// another\nx y z nx ny nz\n" + rows6 + "\n\n")
    (tmp_path / "b.pts").write_text("50\n" + rows3 + "\n")
    (tmp_path / "c.txt").write_text(rows3)
    Q, N, info = load_oriented_points(tmp_path / "a.xyz")
    np.testing.assert_allclose(Q, P, atol=1e-11)
    np.testing.assert_allclose(N, P, atol=1e-11)
    for name in ("b.pts", "c.txt"):
        Q, N, info = load_oriented_points(tmp_path / name)
        np.testing.assert_allclose(Q, P, atol=1e-11)
        assert N is None and info["format"] == name[-3:]


def test_npz_and_point_subset(tmp_path):
    P = sphere_points(300)[0]
    np.savez(tmp_path / "a.npz", points=P, normals=-P)
    Q, N, info = load_oriented_points(tmp_path / "a.npz")
    np.testing.assert_allclose(N, -P)
    Q, N, info = load_oriented_points(tmp_path / "a.npz", n_samples=100, seed=3)
    Q2, _, _ = load_oriented_points(tmp_path / "a.npz", n_samples=100, seed=3)
    assert len(Q) == 100 and info["subsampled"] and len(np.unique(Q, axis=0)) == 100
    np.testing.assert_array_equal(Q, Q2)
    np.testing.assert_allclose(np.sum(N * Q, 1), -1.0, atol=1e-12)   # normals stay paired
    np.savez(tmp_path / "b.npz", points=P)
    assert load_oriented_points(tmp_path / "b.npz")[1] is None


@pytest.mark.parametrize("suffix", [".obj", ".off", ".ply"])
def test_mesh_files_are_sampled_with_face_normals(tmp_path, suffix):
    import trimesh

    V, F = _cube()
    path = tmp_path / f"cube{suffix}"
    trimesh.Trimesh(V, F, process=False).export(path)
    P, N, info = load_oriented_points(path, n_samples=5000)
    assert info["kind"] == "mesh" and info["n_faces"] == 12 and P.shape == N.shape == (5000, 3)
    _check_cube_samples(P, N)
    # Area weighting: every face of the cube gets about 1/6 of the samples.
    counts = np.bincount(np.argmax(np.abs(N), 1) * 2 + (N.max(1) > 0.5), minlength=6)
    np.testing.assert_allclose(counts / 5000, 1 / 6, atol=0.03)
    P_default, _, _ = load_oriented_points(path)
    assert len(P_default) == 100_000
    np.testing.assert_array_equal(load_oriented_points(path, n_samples=50, seed=1)[0],
                                  load_oriented_points(path, n_samples=50, seed=1)[0])


def test_real_bunny_scan():
    P, N, info = load_oriented_points(BUNNY_SCAN)
    assert P.shape == N.shape == (118_245, 3)
    assert info == {"format": "ply", "seed": 0, "subsampled": False, "kind": "points",
                    "n_file": 118_245, "n_points": 118_245, "has_normals": True}
    np.testing.assert_allclose(np.linalg.norm(N, axis=1), 1.0, atol=1e-6)
    # Scan normals point outward: away from the centroid on average.
    assert np.mean(np.sum((P - P.mean(0)) * N, 1) > 0) > 0.7


def _error(path, **kwargs) -> str:
    """The one-line message of ``load_oriented_points(path, **kwargs)``, after ``load_oriented_points(): ``."""
    return value_error(load_oriented_points, path, function="load_oriented_points", **kwargs)


def test_errors(tmp_path):
    t = tmp_path
    assert _error(t / "missing.ply") == f"expected an existing file, got '{t / 'missing.ply'}': no such file"
    (t / "a.stl").write_text("solid")
    assert _error(t / "a.stl") == ("expected a .ply, .xyz, .pts, .txt, .npz, .obj, .off, .glb, .gltf file, "
                                   f"got '{t / 'a.stl'}' (suffix '.stl')")
    (t / "empty.xyz").write_text("# nothing\n")
    assert _error(t / "empty.xyz") == f"expected points in '{t / 'empty.xyz'}', got none (the file holds no points)"
    (t / "bad.ply").write_bytes(b"\x00\x01garbage")
    assert _error(t / "bad.ply") == ("expected a PLY file (a header from 'ply' to 'end_header') in "
                                     f"'{t / 'bad.ply'}', got a file starting b'\\x00\\x01garbage'")
    (t / "bad.npz").write_bytes(b"not a zip")
    assert _error(t / "bad.npz").startswith(f"expected a readable NPZ file '{t / 'bad.npz'}', got ")
    (t / "cols.xyz").write_text("1 2 3 4\n5 6 7 8\n")
    assert _error(t / "cols.xyz") == (f"expected 3 (x y z) or 6 (x y z nx ny nz) columns in '{t / 'cols.xyz'}', "
                                      "got 4 on line 1 = '1 2 3 4'")
    (t / "ragged.xyz").write_text("# x y z\n1 2 3\n5 6 7 8 9 10\n")
    assert _error(t / "ragged.xyz") == (f"expected 3 numbers on every line of '{t / 'ragged.xyz'}' (as on its first "
                                        "data line), got line 3 = '5 6 7 8 9 10'")
    (t / "word.xyz").write_text("1 2 3\n5 six 7\n")
    assert _error(t / "word.xyz") == (f"expected 3 numbers on every line of '{t / 'word.xyz'}' (as on its first "
                                      "data line), got line 2 = '5 six 7'")
    (t / "nan.xyz").write_text("0 0 0\n1 nan 0\n")
    assert _error(t / "nan.xyz") == (f"expected finite points in '{t / 'nan.xyz'}', "
                                     "got point 1 = [1.0, nan, 0.0] (1 such points)")
    P = sphere_points(10)[0]
    N = P.copy()
    N[7] = 0
    N[8] = np.nan
    np.savez(t / "zero.npz", points=P, normals=N)
    assert _error(t / "zero.npz") == (f"expected finite, non-zero normals in '{t / 'zero.npz'}', "
                                      "got normal 7 = [0.0, 0.0, 0.0] (2 such normals)")
    np.savez(t / "count.npz", points=P, normals=P[:9])
    assert _error(t / "count.npz") == (f"expected one normal per point, shape (10, 3), in '{t / 'count.npz'}', "
                                       "got normals of shape (9, 3)")
    np.savez(t / "nopoints.npz", pts=P, extra=P)
    assert _error(t / "nopoints.npz") == ("expected an array 'points' (N, 3) and optional 'normals' (N, 3) in "
                                          f"'{t / 'nopoints.npz'}', got arrays ['extra', 'pts']")
    np.savez(t / "flat.npz", points=P.ravel())
    assert _error(t / "flat.npz") == f"expected points of shape (N, 3) in '{t / 'flat.npz'}', got shape (30,)"
    for bad in (0, -3, 2.5, True):
        assert _error(t / "count.npz", n_samples=bad) == f"expected n_samples a positive integer or None, got {bad!r}"


def test_mesh_errors_name_the_file_and_element(tmp_path):
    (tmp_path / "nan.obj").write_text("v 0 0 0\nv 1 nan 0\nv 0 1 0\nf 1 2 3\n")
    assert _error(tmp_path / "nan.obj") == (f"expected finite vertex coordinates in '{tmp_path / 'nan.obj'}', "
                                            "got vertex 1 = [1.0, nan, 0.0] (1 such vertices)")
    flat = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n" \
           "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n2 0 0\n3 0 1 2\n"
    (tmp_path / "flat.ply").write_text(flat)
    assert _error(tmp_path / "flat.ply") == ("expected a mesh with a positive surface area in "
                                             f"'{tmp_path / 'flat.ply'}', got zero area")
    (tmp_path / "nanmesh.ply").write_text(flat.replace("2 0 0", "2 inf 0"))
    assert _error(tmp_path / "nanmesh.ply") == (f"expected finite vertex coordinates in '{tmp_path / 'nanmesh.ply'}', "
                                                "got vertex 2 = [2.0, inf, 0.0] (1 such vertices)")


def test_obj_without_faces_is_a_point_cloud(tmp_path):
    P = sphere_points(30)[0]
    (tmp_path / "p.obj").write_text("".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in P.tolist()))
    Q, N, info = load_oriented_points(tmp_path / "p.obj")
    np.testing.assert_array_equal(Q, P)
    assert N is None and info["kind"] == "points" and info["format"] == "obj"


def test_ply_with_partial_normals_is_rejected(tmp_path):
    head = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n" \
           "property float z\nproperty float nx\nend_header\n0 0 0 1\n1 0 0 1\n"
    (tmp_path / "p.ply").write_text(head)
    assert _error(tmp_path / "p.ply") == (f"expected PLY vertex normals nx, ny, nz all three or none in "
                                          f"'{tmp_path / 'p.ply'}', got only ['nx']")


def test_an_occupancy_networks_npz_is_read_in_its_own_frame(tmp_path):
    """D-FAUST as Occupancy Flow publishes it: float16 ``points = (X - loc) / scale`` per frame with ``loc``
    and ``scale``; the reader returns X (to float16's precision), and each frame's own loc and scale count."""
    X = np.random.default_rng(0).uniform([-0.3, -0.9, -0.2], [0.4, 0.9, 0.3], size=(500, 3))
    for k, (loc, scale) in enumerate((([0.02, 0.30, -0.08], 1.80), ([-0.01, 0.34, -0.06], 1.88))):
        loc = np.array(loc)
        np.savez(tmp_path / f"{k}.npz", points=((X - loc) / scale).astype(np.float16),
                 loc=loc.astype(np.float16), scale=np.float64(scale))
        P, N, info = load_oriented_points(tmp_path / f"{k}.npz")
        np.testing.assert_allclose(P, X, atol=2e-3 * scale)          # float16: 11 bits of the unit cube
        assert P.dtype == np.float64 and N is None and info["n_points"] == 500
    P = sphere_points(10)[0]
    np.savez(tmp_path / "loc.npz", points=P, loc=np.zeros(3))
    assert _error(tmp_path / "loc.npz") == (f"expected both 'loc' (3,) and 'scale' () with normalised points in "
                                            f"'{tmp_path / 'loc.npz'}', got arrays ['loc', 'points']")
    np.savez(tmp_path / "scale.npz", points=P, loc=np.zeros(3), scale=np.float64(-1.0))
    assert _error(tmp_path / "scale.npz") == (f"expected 'loc' of shape (3,) and a finite 'scale' > 0 in "
                                              f"'{tmp_path / 'scale.npz'}', got loc of shape (3,), scale -1.0")
