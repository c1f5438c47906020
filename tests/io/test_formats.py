"""Mesh file formats (mi_loop.io.formats, mi_loop.io.ply): PLY, OBJ, OFF, glTF/GLB.

Vertex order as stored, polygons split into fans in file order and counted
(``read_control_mesh``), every malformed file refused with a one-line message
that names the file and the vertex, face or line.
"""
from __future__ import annotations

import base64
import json
import re
import struct

import numpy as np
import pytest

import mi_loop
from mi_loop import io
from mi_loop.io.formats import fan_triangulate
from mi_loop.io.ply import read_ply
from mi_loop.mesh.geometry import euler_characteristic

from helpers import DATA, value_error
from meshes import TET_F, TET_V

SQUARE = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0.5], [2, 1, 0.5]], float)
#: A quad, a triangle and a pentagon sharing edges, as the file lists them.
POLYGONS = [[0, 1, 2, 3], [1, 4, 2], [4, 5, 2, 3, 1][::-1]]
#: Their fans from the first corner, in file order.
FANS = [[0, 1, 2], [0, 2, 3], [1, 4, 2], [1, 3, 2], [1, 2, 5], [1, 5, 4]]


def write_ply(path, V, polygons, fmt="ascii", face_extra=False, vertex_extra=False, double=False,
              name="vertex_indices"):
    """A PLY file written independently of mi_loop.io (lists of any length, optional extra properties)."""
    vt = "double" if double else "float"
    head = ["ply", f"format {fmt} 1.0", "comment test", f"element vertex {len(V)}",
            f"property {vt} x", f"property {vt} y", f"property {vt} z"]
    head += ["property uchar red"] if vertex_extra else []
    head += [f"element face {len(polygons)}", f"property list uchar int {name}"]
    head += ["property uchar flags"] if face_extra else []
    head += ["end_header"]
    out = ("\n".join(head) + "\n").encode()
    if fmt == "ascii":
        rows = [" ".join(f"{x!r}" for x in v) + (" 7" if vertex_extra else "") for v in np.asarray(V).tolist()]
        rows += [" ".join(map(str, [len(p), *p])) + (" 1" if face_extra else "") for p in polygons]
        return path.write_bytes(out + ("\n".join(rows) + "\n").encode())
    e = "<" if fmt == "binary_little_endian" else ">"
    for v in np.asarray(V):
        out += struct.pack(e + ("ddd" if double else "fff"), *v) + (b"\x07" if vertex_extra else b"")
    for p in polygons:
        out += struct.pack(e + "B" + "i" * len(p), len(p), *p) + (b"\x01" if face_extra else b"")
    return path.write_bytes(out)


# --------------------------------------------------------------------------
# Polygons: fans in file order, counted
# --------------------------------------------------------------------------

def test_fan_triangulate():
    counts = np.array([len(p) for p in POLYGONS])
    F, n_split = fan_triangulate(counts, np.concatenate(POLYGONS))
    assert F.tolist() == FANS and n_split == 2
    F, n_split = fan_triangulate(np.array([3, 3]), np.array([0, 1, 2, 2, 1, 3]))
    assert F.tolist() == [[0, 1, 2], [2, 1, 3]] and n_split == 0


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian", "binary_big_endian"])
@pytest.mark.parametrize("extras", [False, True])
def test_ply_polygons_any_encoding(tmp_path, fmt, extras):
    """Mixed quads, triangles and pentagons in every PLY encoding, with and without extra properties."""
    write_ply(tmp_path / "m.ply", SQUARE, POLYGONS, fmt, face_extra=extras, vertex_extra=extras, double=extras)
    mesh = io.read_control_mesh(tmp_path / "m.ply")
    np.testing.assert_array_equal(mesh.V, SQUARE)
    assert mesh.F.tolist() == FANS and mesh.n_split == 2
    assert mesh.F.dtype == np.int64 and mesh.V.dtype == np.float64


def test_ply_vertex_index_name_and_every_type(tmp_path):
    write_ply(tmp_path / "m.ply", SQUARE, POLYGONS, "binary_little_endian", name="vertex_index")
    assert io.read_control_mesh(tmp_path / "m.ply").F.tolist() == FANS
    head = ("ply\nformat binary_big_endian 1.0\nelement vertex 1\n" + "".join(
        f"property {t} p{t}\n" for t in ("char", "uchar", "short", "ushort", "int", "uint", "float", "double",
                                         "int8", "uint8", "int16", "uint16", "int32", "uint32", "float32", "float64"))
            + "end_header\n").encode()
    body = struct.pack(">bBhHiIfdbBhHiIfd", -1, 2, -3, 4, -5, 6, 7.5, 8.25, -1, 2, -3, 4, -5, 6, 7.5, 8.25)
    (tmp_path / "t.ply").write_bytes(head + body)
    values = [v[0] for v in read_ply(tmp_path / "t.ply")["vertex"].values()]
    assert values == [-1, 2, -3, 4, -5, 6, 7.5, 8.25] * 2


def test_ply_round_trip_of_shared_control_meshes():
    """mi_loop's reader against trimesh's on the shared control meshes: same vertices, same faces."""
    import trimesh

    for path in sorted((DATA / "control").glob("*.ply")):
        mesh = io.read_control_mesh(path)
        ref = trimesh.load(path, process=False)
        np.testing.assert_array_equal(mesh.V, ref.vertices, err_msg=path.name)
        np.testing.assert_array_equal(mesh.F, ref.faces, err_msg=path.name)
        assert mesh.n_split == 0


def test_obj_polygons_and_corner_forms(tmp_path):
    lines = ["# a comment", "mtllib m.mtl", "o first", *(f"v {x} {y} {z} 0.5 0.5 0.5" for x, y, z in SQUARE),
             "vt 0 0", "vt 1 0", "vn 0 0 1", "g part", "usemtl a", "f 1/1/1 2/2/1 3/1/1 4/2/1",
             "s off", "usemtl b", "f 2//1 5//1 3//1", "", "o second", "f -3/1 -6/2 -4/1 -2 -1"]
    (tmp_path / "m.obj").write_text("\n".join(lines) + "\n")
    mesh = io.read_control_mesh(tmp_path / "m.obj")
    np.testing.assert_array_equal(mesh.V, SQUARE)
    assert mesh.F.tolist() == [[0, 1, 2], [0, 2, 3], [1, 4, 2], [3, 0, 2], [3, 2, 4], [3, 4, 5]]
    assert mesh.n_split == 2


def test_obj_texture_seams_keep_the_file_vertices():
    """Spot's control mesh has UVs with seams: 188 vertices as written (not 267 split ones), quads counted."""
    path = DATA / "static" / "spot_control_mesh.obj"
    mesh = io.read_control_mesh(path)
    V_file = np.array([line.split()[1:4] for line in path.read_text().splitlines() if line.startswith("v ")], float)
    np.testing.assert_array_equal(mesh.V, V_file)
    assert mesh.n_split == 160 + 16 and len(mesh.F) == 160 * 2 + 16 * 3 + 4
    V, F, _ = mi_loop.validate_mesh(mesh.V, mesh.F)
    assert euler_characteristic(len(V), F) == (2, 0)


def test_off_variants(tmp_path):
    V = SQUARE
    body = [" ".join(map(repr, v)) + " 255 0 0" for v in V.tolist()]
    faces = [" ".join(map(str, [len(p), *p])) + " 0.1 0.2 0.3" for p in POLYGONS]
    variants = {
        "a.off": ["OFF", "# counts next", f"{len(V)} {len(POLYGONS)} 0", *body, *faces],
        "b.off": [f"COFF {len(V)} {len(POLYGONS)} 0", *body, "", *faces],
        "c.off": [f"{len(V)} {len(POLYGONS)} 0", *body, *faces],              # no header line
    }
    for name, lines in variants.items():
        (tmp_path / name).write_text("\n".join(lines) + "\n")
        mesh = io.read_control_mesh(tmp_path / name)
        np.testing.assert_array_equal(mesh.V, V, err_msg=name)
        assert mesh.F.tolist() == FANS and mesh.n_split == 2, name


def test_triangle_meshes_report_no_split(tmp_path):
    V, F = mi_loop.datasets.blob()
    io.write_ply(tmp_path / "b.ply", V, F)
    mesh = io.read_control_mesh(tmp_path / "b.ply")
    assert mesh.n_split == 0
    np.testing.assert_array_equal(mesh.F, F)
    np.testing.assert_array_equal(io.read_mesh(tmp_path / "b.ply")[1], F)


def test_validate_mesh_still_refuses_polygons():
    with pytest.raises(ValueError, match=re.escape("expected faces of shape (m, 3) with m > 0 (triangles only), "
                                                   "got shape (1, 4)")):
        mi_loop.validate_mesh(SQUARE, [[0, 1, 2, 3]])


# --------------------------------------------------------------------------
# Messages
# --------------------------------------------------------------------------

def test_nan_written_as_text(tmp_path):
    """The issue's case: 'v nan 0 0' names the vertex; so do PLY and OFF; an unparsable token names the line."""
    (tmp_path / "n.obj").write_text("v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    assert value_error(io.read_mesh, tmp_path / "n.obj") == (
        f"read_mesh(): expected finite vertex coordinates in '{tmp_path / 'n.obj'}', "
        "got vertex 0 = [nan, 0.0, 0.0] (1 such vertices)")
    (tmp_path / "n.off").write_text("OFF\n3 1 0\n0 0 0\n1 -inf 0\n0 1 0\n3 0 1 2\n")
    assert value_error(io.read_mesh, tmp_path / "n.off") == (
        f"read_mesh(): expected finite vertex coordinates in '{tmp_path / 'n.off'}', "
        "got vertex 1 = [1.0, -inf, 0.0] (1 such vertices)")
    V = SQUARE.copy()
    V[4, 2] = np.nan
    write_ply(tmp_path / "n.ply", V, POLYGONS, "binary_little_endian")
    assert value_error(io.read_control_mesh, tmp_path / "n.ply") == (
        f"read_control_mesh(): expected finite vertex coordinates in '{tmp_path / 'n.ply'}', "
        "got vertex 4 = [2.0, 0.0, nan] (1 such vertices)")
    (tmp_path / "q.obj").write_text("v 0 0 0\nv 1.#QNAN 0 0\nv 0 1 0\nf 1 2 3\n")
    assert value_error(io.read_mesh, tmp_path / "q.obj") == (
        f"read_mesh(): expected vertex lines 'v x y z' with three numbers in '{tmp_path / 'q.obj'}', "
        "got line 2 = 'v 1.#QNAN 0 0'")


@pytest.mark.parametrize("name, text, message", [
    ("short.obj", "v 0 0\n", "expected vertex lines 'v x y z' with three numbers in '{p}', got line 1 = 'v 0 0'"),
    ("two.obj", "v 0 0 0\nv 1 0 0\n# x\nf 1 2\n", "expected faces with at least 3 corners in '{p}', got line 4 = 'f 1 "
                                                  "2'"),
    ("zero.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n",
     "expected face corners that index the file's 3 vertices in '{p}', got line 4 = 'f 0 1 2'"),
    ("far.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n",
     "expected face corners that index the file's 3 vertices in '{p}', got line 5 = 'f 1 3 4'"),
    ("before.obj", "v 0 0 0\nf -1 -2 -3\nv 1 0 0\nv 0 1 0\n",
     "expected face corners that index the file's 3 vertices in '{p}', got line 2 = 'f -1 -2 -3'"),
    ("word.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf a/1 2 3\n",
     "expected face corners 'i', 'i/t', 'i//n' or 'i/t/n' with integer i in '{p}', got line 5 = 'f a/1 2 3'"),
    ("bin.off", "OFF BINARY\n3 1 0\n",
     "expected an ASCII 3-D OFF file (header OFF, COFF, NOFF or CNOFF) in '{p}', got line 1 = 'OFF BINARY'"),
    ("four.off", "4OFF\n1 0 0\n0 0 0 1\n",
     "expected an ASCII 3-D OFF file (header OFF, COFF, NOFF or CNOFF) in '{p}', got line 1 = '4OFF'"),
    ("nocounts.off", "OFF\nthree one zero\n",
     "expected the counts 'n_vertices n_faces n_edges' in '{p}', got line 2 = 'three one zero'"),
    ("cut.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n",
     "expected 3 vertex and 1 face lines in '{p}', got 2 lines (the file ends early)"),
    ("far.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n",
     "expected face corners that index the file's 3 vertices in '{p}', got line 6 = '3 0 1 3'"),
    ("count.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n4 0 1 2\n",
     "expected face lines 'k i_1 ... i_k' in '{p}', got line 6 = '4 0 1 2'"),
    ("word.off", "OFF\n3 1 0\n0 0 0\n1 x 0\n0 1 0\n3 0 1 2\n", "expected vertex lines 'x y z' in '{p}', got line 4 = "
                                                               "'1 x 0'"),
    ("hdr.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty floaty x\nend_header\n",
     "expected a valid PLY header in '{p}', got header line 4 = 'property floaty x'"),
    ("fmt.ply", "ply\nformat utf8 1.0\nend_header\n", "expected a valid PLY header in '{p}', got header line 2 = "
                                                      "'format utf8 1.0'"),
    ("noformat.ply", "ply\nelement vertex 0\nend_header\n", "expected a 'format' line in the PLY header of '{p}', got "
                                                            "none"),
    ("rows.ply", ("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
                  "end_header\n0 0 0\n1 1\n"), "expected 3 numbers per 'vertex' line in '{p}', got line 9 = '1 1'"),
    ("few.ply", ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                 "end_header\n0 0 0\n1 1 1\n"), "expected 3 'vertex' lines in '{p}', got 2 (the file ends early)"),
    ("face.ply", ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                  "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n4 0 1 2\n"),
     "expected 'face' lines as the header declares them in '{p}', got line 13 = '4 0 1 2'"),
    ("range.ply", ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                   "element face 2\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n"
                   "3 0 1 2\n3 0 2 3\n"), "expected face corners that index the file's 3 vertices in '{p}', got face 1 "
                                          "= [0, 2, 3]"),
    ("xyz.ply", "ply\nformat ascii 1.0\nelement point 1\nproperty float x\nend_header\n0\n",
     "expected a PLY 'vertex' element with properties x, y, z in '{p}', got elements ['point'] with vertex properties "
     "[]"),
    ("lists.ply", ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                   "element face 1\nproperty int nope\nend_header\n0 0 0\n1 0 0\n0 1 0\n5\n"),
     "expected a PLY 'face' element with a list property vertex_indices in '{p}', got face properties ['nope']"),
])
def test_malformed_files_named(tmp_path, name, text, message):
    path = tmp_path / name
    path.write_text(text)
    assert value_error(io.read_mesh, path) == "read_mesh(): " + message.format(p=path)


def test_binary_ply_that_ends_early(tmp_path):
    write_ply(tmp_path / "m.ply", SQUARE, POLYGONS, "binary_little_endian")
    data = (tmp_path / "m.ply").read_bytes()
    (tmp_path / "v.ply").write_bytes(data[:data.index(b"end_header") + 11 + 40])
    assert value_error(io.read_mesh, tmp_path / "v.ply") == (
        f"read_mesh(): expected 6 'vertex' records (72 bytes) in '{tmp_path / 'v.ply'}', got 40 bytes left "
        "(the file ends early)")
    (tmp_path / "f.ply").write_bytes(data[:-3])
    assert value_error(io.read_mesh, tmp_path / "f.ply") == (
        f"read_mesh(): expected 3 'face' records in '{tmp_path / 'f.ply'}', got fewer bytes (the file ends early)")


# --------------------------------------------------------------------------
# glTF / GLB
# --------------------------------------------------------------------------

def write_gltf(path, meshes, nodes):
    """A .gltf file with an embedded buffer: ``meshes`` = [[(V, F), ...primitives], ...], ``nodes`` = [dict]."""
    blob, views, accessors, out_meshes = b"", [], [], []
    for primitives in meshes:
        prims = []
        for V, F in primitives:
            for array, kind, ctype in ((np.asarray(V, np.float32), "VEC3", 5126),
                                       (np.asarray(F, np.uint32).ravel(), "SCALAR", 5125)):
                views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": array.nbytes})
                acc = {"bufferView": len(views) - 1, "componentType": ctype, "count": len(array), "type": kind}
                if kind == "VEC3":
                    acc.update(min=array.min(0).tolist(), max=array.max(0).tolist())
                accessors.append(acc)
                blob += array.tobytes()
            prims.append({"attributes": {"POSITION": len(accessors) - 2}, "indices": len(accessors) - 1})
        out_meshes.append({"primitives": prims})
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": list(range(len(nodes)))}], "nodes": nodes,
           "meshes": out_meshes, "accessors": accessors, "bufferViews": views,
           "buffers": [{"byteLength": len(blob),
                        "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()}]}
    path.write_text(json.dumps(doc))


def test_gltf_primitives_are_merged_and_welded(tmp_path):
    """One mesh in two primitives, each with its own copies of the shared vertices: one closed tetrahedron."""
    halves = [(TET_V[[0, 1, 2, 3]], TET_F[:2]), (TET_V[[0, 1, 2, 3]][[0, 3, 1, 2]], [[0, 1, 2], [2, 1, 3]])]
    write_gltf(tmp_path / "t.gltf", [halves], [{"mesh": 0, "name": "tet"}])
    mesh = io.read_control_mesh(tmp_path / "t.gltf")
    np.testing.assert_array_equal(mesh.V, TET_V)          # first appearance order
    assert mesh.n_split == 0 and sorted(map(sorted, mesh.F.tolist())) == sorted(map(sorted, TET_F.tolist()))
    V, F, _ = mi_loop.validate_mesh(mesh.V, mesh.F)
    assert euler_characteristic(len(V), F) == (2, 0)


def test_gltf_node_transform_applied(tmp_path):
    write_gltf(tmp_path / "t.gltf", [[(TET_V, TET_F)]],
               [{"mesh": 0, "translation": [10.0, 0, 0], "scale": [2.0, 2, 2]}])
    V, F = io.read_mesh(tmp_path / "t.gltf")
    np.testing.assert_allclose(V, 2.0 * TET_V + [10, 0, 0], rtol=0, atol=1e-6)
    np.testing.assert_array_equal(F, TET_F)


def test_gltf_with_several_meshes(tmp_path):
    """A control mesh must be one object; the fitting target may be several (all sampled, each in place)."""
    write_gltf(tmp_path / "two.gltf", [[(TET_V, TET_F)], [(TET_V, TET_F)]],
               [{"mesh": 0, "name": "left"}, {"mesh": 1, "name": "right", "translation": [5.0, 0, 0]}])
    assert value_error(io.read_mesh, tmp_path / "two.gltf") == (
        f"read_mesh(): expected one mesh in '{tmp_path / 'two.gltf'}', got 2 meshes (nodes 'left', 'right'); "
        "export the one to use alone")
    P, _, info = io.load_oriented_points(tmp_path / "two.gltf", n_samples=2000)
    assert info["kind"] == "mesh" and info["n_file"] == 8 and info["n_faces"] == 8
    assert (P[:, 0] < 1 + 1e-6).sum() > 700 and (P[:, 0] > 4 - 1e-6).sum() > 700


def test_gltf_errors(tmp_path):
    (tmp_path / "bad.glb").write_bytes(b"glTF not really")
    assert value_error(io.read_mesh, tmp_path / "bad.glb").startswith(
        f"read_mesh(): expected a readable glTF file '{tmp_path / 'bad.glb'}', got ")
    write_gltf(tmp_path / "n.gltf", [[(np.where(TET_V == -1, np.nan, TET_V), TET_F)]], [{"mesh": 0}])
    assert value_error(io.read_mesh, tmp_path / "n.gltf").startswith(
        f"read_mesh(): expected finite vertex coordinates in '{tmp_path / 'n.gltf'}', got vertex 1 = [1.0, nan, nan]")


def test_shared_fox_glb():
    """The skinned fox (rest pose): 1728 seam-split vertices weld to the 290 of the baked sequence, closed genus 0."""
    fox = DATA / "sequences" / "Fox.glb"
    mesh = io.read_control_mesh(fox)
    baked = np.load(DATA / "sequences" / "fox_walk_24f.npz")
    assert mesh.V.shape == (baked["vertices"].shape[1], 3) == (290, 3)
    assert mesh.F.shape == baked["faces"].shape and mesh.n_split == 0
    V, F, kept = mi_loop.validate_mesh(mesh.V, mesh.F)
    assert len(kept) == 290 and euler_characteristic(len(V), F) == (2, 0)
    _, _, info = io.load_oriented_points(fox, n_samples=1000)
    assert info["kind"] == "mesh" and info["format"] == "glb" and info["n_file"] == 290
    frames = io.read_frames([fox])
    frame = frames[0]()
    assert len(frames) == 1 and frame.name == "Fox.glb" and frame.normals is None
    np.testing.assert_array_equal(frame.vertices, mesh.V)
    np.testing.assert_array_equal(frame.faces, mesh.F)
