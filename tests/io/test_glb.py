"""GLB files written by mi_loop.io.glb, read back independently: the container's layout rules, trimesh,
the accessors, the morph targets and their animation, and the glTF baker of mi_loop.io.animation."""
from __future__ import annotations

import json
import struct

import numpy as np
import pytest

import mi_loop
from mi_loop import datasets
from mi_loop.io.animation import bake_animation
from mi_loop.io.glb import ROUGHNESS, write_glb, write_glb_sequence
from mi_loop.subdiv.masks import limit_colors, limit_mesh

from helpers import check_bounds, exactly, parse_glb


@pytest.fixture(scope="module")
def blob_view():
    """The blob's limit surface at level 2 and its colours (a smooth ramp of linear RGB)."""
    V, F = datasets.blob()
    P, F_t, N = limit_mesh(V, F, 2)
    albedo = np.clip(0.5 + 0.4 * V / np.abs(V).max(), 0, 1)
    return V, F, P, F_t, N, limit_colors(albedo, F, 2)


def test_a_static_glb_holds_the_mesh_its_normals_and_colours(blob_view, tmp_path):
    import trimesh

    _, _, P, F_t, N, C = blob_view
    path = write_glb(tmp_path / "limit.glb", P, F_t, N, colors=C)
    doc, read = parse_glb(path)
    assert doc["asset"] == {"version": "2.0", "generator": f"mi_loop {mi_loop.__version__}"}
    prim, = doc["meshes"][0]["primitives"]
    assert prim["mode"] == 4 and "targets" not in prim and "animations" not in doc
    attrs = prim["attributes"]
    np.testing.assert_array_equal(read(attrs["POSITION"]), P.astype(np.float32))
    check_bounds(doc, read, attrs["POSITION"])
    np.testing.assert_allclose(read(attrs["NORMAL"]), N, atol=1e-7)
    np.testing.assert_allclose(np.linalg.norm(read(attrs["NORMAL"]), axis=1), 1.0, atol=1e-6)
    np.testing.assert_array_equal(read(attrs["COLOR_0"]), C.astype(np.float32))      # linear, as glTF says
    indices = read(prim["indices"])
    assert doc["accessors"][prim["indices"]]["componentType"] == 5125                   # uint32
    np.testing.assert_array_equal(indices.reshape(-1, 3), F_t)
    assert indices.min() == 0 and indices.max() == len(P) - 1
    material = doc["materials"][prim["material"]]
    assert material["doubleSided"] is True
    pbr = material["pbrMetallicRoughness"]
    assert (pbr["roughnessFactor"], pbr["metallicFactor"], pbr["baseColorFactor"]) == (ROUGHNESS, 0.0, [1.0] * 4)
    assert doc["scenes"][doc["scene"]]["nodes"] == [0] and doc["nodes"][0]["mesh"] == 0

    mesh = trimesh.load(path, force="mesh", process=False)          # a third-party reader agrees
    np.testing.assert_allclose(mesh.vertices, P, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(mesh.faces, F_t)


def test_without_colours_the_material_is_grey(blob_view, tmp_path):
    _, _, P, F_t, N, _ = blob_view
    doc, _ = parse_glb(write_glb(tmp_path / "grey.glb", P, F_t, 3.0 * N))
    assert "COLOR_0" not in doc["meshes"][0]["primitives"][0]["attributes"]
    assert doc["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"] == [0.8, 0.8, 0.8, 1.0]


def moving_blob(T=5, level=1):
    """``T`` frames of the blob bending and moving (limit surface at ``level``): ``(P, F_t, N)``."""
    V, F = datasets.blob()
    frames = [limit_mesh(V + [0.1 * t, 0.0, 0.0] + 0.05 * t * np.sin(2 * V[:, [1, 2, 0]]), F, level) for t in range(T)]
    return np.stack([f[0] for f in frames]), frames[0][1], np.stack([f[2] for f in frames])


def test_a_sequence_is_one_mesh_with_a_morph_target_per_frame_and_a_step_animation(tmp_path):
    import trimesh

    P, F_t, N = moving_blob()
    names = [f"walk[{t}]" for t in range(5)]
    path = write_glb_sequence(tmp_path / "sequence.glb", P, F_t, N, fps=24.0, names=names)
    doc, read = parse_glb(path)
    mesh, = doc["meshes"]
    prim, = mesh["primitives"]
    base = read(prim["attributes"]["POSITION"])
    np.testing.assert_array_equal(base, P[0].astype(np.float32))              # frame 0 is the mesh
    assert len(prim["targets"]) == 5 and len(base) == P.shape[1]
    for k, target in enumerate(prim["targets"]):
        assert doc["accessors"][target["POSITION"]]["count"] == len(base)
        check_bounds(doc, read, target["POSITION"])
        np.testing.assert_allclose(base + read(target["POSITION"]), P[k], rtol=0, atol=1e-6)
        np.testing.assert_allclose(read(prim["attributes"]["NORMAL"]) + read(target["NORMAL"]), N[k], atol=1e-6)
    assert mesh["weights"] == [1.0, 0.0, 0.0, 0.0, 0.0] and mesh["extras"]["targetNames"] == names
    animation, = doc["animations"]
    sampler, = animation["samplers"]
    assert sampler["interpolation"] == "STEP"
    assert animation["channels"] == [{"sampler": 0, "target": {"node": 0, "path": "weights"}}]
    times = read(sampler["input"]).ravel()
    np.testing.assert_array_equal(times, (np.arange(5) / 24.0).astype(np.float32))     # frame k at k / fps
    check_bounds(doc, read, sampler["input"])
    np.testing.assert_array_equal(read(sampler["output"]).reshape(5, 5), np.eye(5))     # one-hot per keyframe
    mesh = trimesh.load(path, force="mesh", process=False)                     # the base mesh, for trimesh
    np.testing.assert_allclose(mesh.vertices, P[0], rtol=0, atol=1e-6)


@pytest.mark.parametrize("fps", [24.0, 30.0, 7.0])
def test_the_glTF_baker_reads_the_frames_back(tmp_path, fps):
    """mi_loop's own glTF reader plays the morph targets: frame k at k / fps (float32 key times
    rounded up, as 1/24 is, still give frame k), the faces, the frame count."""
    P, F_t, N = moving_blob()
    path = write_glb_sequence(tmp_path / "sequence.glb", P, F_t, N, fps=fps)
    baked = bake_animation(path, "sequence", fps=fps)
    assert len(baked.vertices) == 5 and baked.fps == fps
    np.testing.assert_array_equal(baked.faces, F_t)                  # the limit tessellation has no seams
    np.testing.assert_allclose(baked.vertices, P, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(baked.colors, 0.8)                 # the grey material's base colour


def test_a_one_frame_sequence_and_colours(blob_view, tmp_path):
    _, _, P, F_t, N, C = blob_view
    doc, read = parse_glb(write_glb_sequence(tmp_path / "one.glb", P[None], F_t, N[None], colors=C))
    assert len(doc["meshes"][0]["primitives"][0]["targets"]) == 1 and doc["meshes"][0]["weights"] == [1.0]
    assert doc["meshes"][0]["extras"]["targetNames"] == ["frame 0"]
    baked = bake_animation(tmp_path / "one.glb")
    np.testing.assert_allclose(baked.colors, C, atol=1e-6)


# -- rejected input: one ValueError naming what was expected --------------------------


def bad_static(P, F_t, N, C):
    return {
        "V not (n, 3)": ((P[:, :2], F_t, N), "write_glb(): expected V of shape (n, 3), n > 0, got shape (162, 2)"),
        "NaN vertex": ((np.where(np.arange(len(P))[:, None] == 7, np.nan, P), F_t, N),
                       "write_glb(): expected finite vertex positions, got vertex 7 = [nan, nan, nan]"),
        "float faces": ((P, F_t.astype(float), N), "write_glb(): expected integer faces F of shape (m, 3), m > 0, "
                                                   "got float64 array of shape (320, 3)"),
        "face out of range": ((P, np.vstack([F_t, [[0, 1, 162]]]), N),
                              "write_glb(): expected face indices in [0, 162), got face 320 = [0, 1, 162]"),
        "normals' shape": ((P, F_t, N[:-1]), "write_glb(): expected normals of V's shape (162, 3), got shape (161, 3)"),
        "zero normal": ((P, F_t, np.where(np.arange(len(P))[:, None] == 3, 0.0, N)),
                        "write_glb(): expected finite, non-zero normals, got normal 3 = [0.0, 0.0, 0.0]"),
        "colours' shape": ((P, F_t, N, C[:, :2]), "write_glb(): expected colors of shape (162, 3), got shape (162, 2)"),
        "colour above 1": ((P, F_t, N, np.where(np.arange(len(P))[:, None] == 5, 1.5, C)),
                           "write_glb(): expected linear RGB colors in [0, 1], got color 5 = [1.5, 1.5, 1.5]"),
    }


@pytest.mark.parametrize("case", list(bad_static(*[np.zeros((1, 3))] * 4)))
def test_write_glb_rejects(case, tmp_path):
    V, F = datasets.blob()
    P, F_t, N = limit_mesh(V, F, 1)
    args, message = bad_static(P, F_t, N, np.full_like(P, 0.5))[case]
    with pytest.raises(ValueError, match=exactly(message)):
        write_glb(tmp_path / "x.glb", *args)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("kwargs, message", [
    ({"fps": 0.0}, "write_glb_sequence(): expected fps, a finite number > 0, got 0.0"),
    ({"fps": float("nan")}, "write_glb_sequence(): expected fps, a finite number > 0, got nan"),
    ({"names": ["a", "b"]}, "write_glb_sequence(): expected one name per frame (5 frames), got 2 names"),
])
def test_write_glb_sequence_rejects_bad_rates_and_names(kwargs, message, tmp_path):
    P, F_t, N = moving_blob()
    with pytest.raises(ValueError, match=exactly(message)):
        write_glb_sequence(tmp_path / "x.glb", P, F_t, N, **kwargs)
    assert list(tmp_path.iterdir()) == []


def test_write_glb_sequence_rejects_a_rate_that_is_not_a_number(tmp_path):
    P, F_t, N = moving_blob()
    with pytest.raises(TypeError, match=exactly("write_glb_sequence(): expected fps as a number, got str '24'")):
        write_glb_sequence(tmp_path / "x.glb", P, F_t, N, fps="24")


def test_write_glb_sequence_names_the_frame_of_a_bad_vertex_or_normal(tmp_path):
    P, F_t, N = moving_blob()
    with pytest.raises(ValueError, match=exactly("write_glb_sequence(): expected V of shape (T, n, 3), T > 0, n > 0, "
                                                 "got shape (162, 3)")):
        write_glb_sequence(tmp_path / "x.glb", P[0], F_t, N[0])
    P[3, 9, 1] = np.inf
    with pytest.raises(ValueError, match=r"got vertex 9 = \[.*, inf, .*\] in frame 3$"):
        write_glb_sequence(tmp_path / "x.glb", P, F_t, N)
    P[3, 9, 1] = 0.0
    N[2, 4] = np.nan
    with pytest.raises(ValueError, match=r"expected finite, non-zero normals, got normal 4 = \[nan, nan, nan\] "
                                         r"in frame 2$"):
        write_glb_sequence(tmp_path / "x.glb", P, F_t, N)
    assert list(tmp_path.iterdir()) == []


def repacked(path, edit):
    """Rewrite a GLB file's JSON chunk with ``edit(doc)`` applied (the BIN chunk kept)."""
    data = path.read_bytes()
    json_length = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(data[20:20 + json_length])
    edit(doc)
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    tail = data[20 + json_length:]
    path.write_bytes(struct.pack("<4sII", b"glTF", 2, 20 + len(text) + len(tail))
                     + struct.pack("<II", len(text), 0x4E4F534A) + text + tail)
    return path


def test_the_baker_takes_the_default_weights_without_an_animated_channel_and_checks_their_count(tmp_path):
    P, F_t, N = moving_blob()
    path = write_glb_sequence(tmp_path / "sequence.glb", P, F_t, N, fps=10.0)

    def still(doc):                          # the animation no longer drives the weights: the mesh's default
        doc["animations"][0]["channels"] = []
        doc["meshes"][0]["weights"] = [0.0, 0.0, 1.0, 0.0, 0.0]
    baked = bake_animation(repacked(path, still), fps=10.0)
    np.testing.assert_allclose(baked.vertices, np.broadcast_to(P[2], P.shape), rtol=0, atol=1e-6)

    def short(doc):
        doc["meshes"][0]["weights"] = [1.0, 0.0, 0.0]
    with pytest.raises(ValueError, match=exactly(f"bake_animation(): expected one morph weight per target (5) of "
                                                 f"mesh 0 in '{path}', got 3 weights")):
        bake_animation(repacked(path, short), fps=10.0)
