"""Baked glTF animations (mi_loop.io.animation, mi_loop.io.gltf): skinning, interpolation, welding, colours.

Oracles: hand-computed linear-blend skinning of a two-joint strip (slerp, step),
the Hermite formula of a cubic-spline channel, a 2x2 texture of known texels,
the Fox's rest pose (its joints' node transforms are its bind pose) against
trimesh's reader, and the shared ``fox_walk_24f.npz``, baked from the same
file by another tool. Every refusal is checked word for word.
"""
from __future__ import annotations

import io as bytes_io
import json
import math
import struct
import warnings

import numpy as np
import pytest
from PIL import Image

from mi_loop import io
from mi_loop.io.animation import animation_names, bake_animation
from mi_loop.io.gltf import sample_texture
from mi_loop.io.srgb import srgb_to_linear
from mi_loop.mesh.geometry import connected_components, euler_characteristic
from mi_loop.mesh.topology import validate_mesh

from helpers import DATA, exactly, value_error

FOX = DATA / "sequences" / "Fox.glb"
FOX_NPZ = DATA / "sequences" / "fox_walk_24f.npz"
_CTYPES = {"<f4": 5126, "|u1": 5121, "<u2": 5123, "<u4": 5125}


class Glb:
    """A GLB file under construction: :meth:`add` appends an accessor to its one binary buffer."""

    def __init__(self, doc=None, blob=b""):
        self.doc = {"asset": {"version": "2.0"}, **(doc or {})}
        self.blob = bytearray(blob)

    def view(self, raw: bytes) -> int:
        self.blob += b"\0" * (-len(self.blob) % 4)
        views = self.doc.setdefault("bufferViews", [])
        views.append({"buffer": 0, "byteOffset": len(self.blob), "byteLength": len(raw)})
        self.blob += raw
        return len(views) - 1

    def add(self, array, kind: str, dtype: str = "<f4", normalized: bool = False) -> int:
        a = np.ascontiguousarray(array, dtype=dtype)
        acc = {"bufferView": self.view(a.tobytes()), "componentType": _CTYPES[a.dtype.str], "count": len(a),
               "type": kind, **({"normalized": True} if normalized else {})}
        self.doc.setdefault("accessors", []).append(acc)
        return len(self.doc["accessors"]) - 1

    @classmethod
    def read(cls, path) -> Glb:
        """An existing GLB (JSON chunk, then BIN chunk), to add to."""
        data = path.read_bytes()
        size = struct.unpack_from("<I", data, 12)[0]
        return cls(json.loads(data[20:20 + size]), data[20 + size + 8:])

    def write(self, path):
        self.doc["buffers"] = [{"byteLength": len(self.blob)}]
        js = json.dumps(self.doc).encode()
        js += b" " * (-len(js) % 4)
        data = bytes(self.blob) + b"\0" * (-len(self.blob) % 4)
        body = struct.pack("<II", len(js), 0x4E4F534A) + js + struct.pack("<II", len(data), 0x004E4942) + data
        path.write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body)
        return path


def z_quaternion(degrees: float) -> list:
    half = math.radians(degrees) / 2
    return [0.0, 0.0, math.sin(half), math.cos(half)]


def add_animation(glb: Glb, name: str, node: int, path: str, times, values, kind: str, interpolation="LINEAR"):
    sampler = {"input": glb.add(np.asarray(times).reshape(-1, 1), "SCALAR"),
               "output": glb.add(values, kind), "interpolation": interpolation}
    glb.doc.setdefault("animations", []).append(
        {"name": name, "samplers": [sampler], "channels": [{"sampler": 0, "target": {"node": node, "path": path}}]})


# A strip of two quads along x: vertices 0, 1 on joint 0, 2, 3 on both, 4, 5 on joint 1.
STRIP_V = np.array([[0, 0, 0], [0, 1, 0], [1, 0, 0], [1, 1, 0], [2, 0, 0], [2, 1, 0]], dtype=float)
STRIP_F = np.array([[0, 2, 1], [1, 2, 3], [2, 4, 3], [3, 4, 5]])
STRIP_W1 = np.array([0.0, 0.0, 0.5, 0.5, 1.0, 1.0])          # weight of joint 1


def skinned_strip(tmp_path, weights=("<f4", False, 1.0)):
    """Joint 0 at the origin, joint 1 at x = 1 rotating 0 -> 90 degrees about z over 1 s (LINEAR and STEP).

    The mesh node is translated by 100 along x: a skinned mesh ignores its node's transform.
    """
    dtype, normalized, one = weights
    glb = Glb({"scene": 0, "scenes": [{"nodes": [0, 1]}],
               "nodes": [{"mesh": 0, "skin": 0, "translation": [100.0, 0, 0]},
                         {"name": "j0", "children": [2]}, {"name": "j1", "translation": [1.0, 0, 0]}]})
    W = np.c_[1 - STRIP_W1, STRIP_W1, np.zeros((6, 2))] * one              # 128: a half in unsigned bytes
    ibm = np.stack([np.eye(4), np.eye(4)])
    ibm[1, 0, 3] = -1.0                                         # inverse of joint 1's bind transform
    attrs = {"POSITION": glb.add(STRIP_V, "VEC3"), "JOINTS_0": glb.add(np.tile([0, 1, 0, 0], (6, 1)), "VEC4", "<u2"),
             "WEIGHTS_0": glb.add(W, "VEC4", dtype, normalized)}
    glb.doc["meshes"] = [{"primitives": [{"attributes": attrs, "indices": glb.add(STRIP_F.ravel(), "SCALAR", "<u4")}]}]
    ibm = glb.add(ibm.transpose(0, 2, 1).reshape(2, 16), "MAT4")              # column-major
    glb.doc["skins"] = [{"joints": [1, 2], "inverseBindMatrices": ibm}]
    add_animation(glb, "Bend", 2, "rotation", [0.0, 1.0], [z_quaternion(0), z_quaternion(90)], "VEC4")
    add_animation(glb, "Snap", 2, "rotation", [0.0, 1.0], [z_quaternion(0), z_quaternion(90)], "VEC4", "STEP")
    return glb.write(tmp_path / "strip.glb")


def strip_bent(degrees: float) -> np.ndarray:
    """Linear-blend skinning by hand: (1 - w) p + w (R (p - e_x) + e_x)."""
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    q = STRIP_V - [1.0, 0, 0]
    rotated = np.c_[c * q[:, 0] - s * q[:, 1], s * q[:, 0] + c * q[:, 1], q[:, 2]] + [1.0, 0, 0]
    return (1 - STRIP_W1)[:, None] * STRIP_V + STRIP_W1[:, None] * rotated


@pytest.mark.parametrize("weights", [("<f4", False, 1.0), ("<f4", False, 3.0), ("|u1", True, 128), ("<u2", True, 1000)],
                         ids=["float", "float-unnormalised", "ubyte", "ushort"])
def test_two_joint_skin_by_hand(tmp_path, weights):
    """90 degrees at t = 1: the tip (2, 0, 0) -> (1, 1, 0), the half-weighted (1, 1, 0) -> (0.5, 0.5, 0)."""
    baked = bake_animation(skinned_strip(tmp_path, weights), "Bend", fps=4, weld=False)
    np.testing.assert_allclose(baked.times, [0, 0.25, 0.5, 0.75, 1.0])
    np.testing.assert_allclose(baked.vertices[0], STRIP_V, atol=1e-12)
    np.testing.assert_allclose(baked.vertices[4, [4, 5, 3, 2]], [[1, 1, 0], [0, 1, 0], [0.5, 0.5, 0], [1, 0, 0]],
                               atol=1e-6)
    for k, degrees in enumerate([0.0, 22.5, 45.0, 67.5, 90.0]):       # slerp: the angle is linear in t
        np.testing.assert_allclose(baked.vertices[k], strip_bent(degrees), atol=1e-6)
    np.testing.assert_array_equal(baked.faces, STRIP_F)
    assert baked.colors is None and baked.animation == "Bend" and baked.fps == 4.0
    assert baked.names[1] == "strip.glb[Bend#1@0.250s]"


def test_step_holds_the_previous_keyframe(tmp_path):
    baked = bake_animation(skinned_strip(tmp_path), "Snap", fps=4)
    for k in range(4):
        np.testing.assert_allclose(baked.vertices[k], STRIP_V, atol=1e-12)
    np.testing.assert_allclose(baked.vertices[4], strip_bent(90.0), atol=1e-6)


def test_cubic_spline_translation_of_a_static_mesh(tmp_path):
    """Hermite on keys t = 0, 2 (v 0 -> 1, out-tangent 3): x = 0, 1, 1.25, 1.125, 1 at t = 0 ... 2; parent scale 2."""
    glb = Glb({"scenes": [{"nodes": [0]}], "nodes": [{"scale": [2.0, 2, 2], "children": [1]}, {"mesh": 0}]})
    attrs = {"POSITION": glb.add(STRIP_V, "VEC3")}
    glb.doc["meshes"] = [{"primitives": [{"attributes": attrs, "indices": glb.add(STRIP_F.ravel(), "SCALAR", "<u4")}]}]
    tangents_values = [[0, 0, 0], [0, 0, 0], [3, 0, 0], [0, 0, 0], [1, 0, 0], [0, 0, 0]]
    add_animation(glb, "Slide", 1, "translation", [0.0, 2.0], tangents_values, "VEC3", "CUBICSPLINE")
    baked = bake_animation(glb.write(tmp_path / "slide.glb"), fps=2)
    for k, x in enumerate([0.0, 1.0, 1.25, 1.125, 1.0]):
        np.testing.assert_allclose(baked.vertices[k], 2 * (STRIP_V + [x, 0, 0]), atol=1e-12)


@pytest.mark.parametrize(("fps", "count"), [(24.0, 25), (7.0, 8), (0.5, 1), (1.0, 2)])
def test_frame_count_is_floor_duration_fps_plus_one(tmp_path, fps, count):
    baked = bake_animation(skinned_strip(tmp_path), "Bend", fps=fps)
    assert len(baked.times) == len(baked.names) == len(baked.vertices) == count == math.floor(1.0 * fps) + 1
    np.testing.assert_allclose(baked.times, np.arange(count) / fps)


def test_frames_span_one_period(tmp_path):
    baked = bake_animation(skinned_strip(tmp_path), "Bend", frames=4)
    np.testing.assert_allclose(baked.times, [0, 0.25, 0.5, 0.75])
    assert baked.fps == 4.0
    np.testing.assert_allclose(baked.vertices[3], strip_bent(67.5), atol=1e-6)


def test_weld_merges_seams_and_averages_colours(tmp_path):
    """The strip in two primitives (red, blue) sharing vertices 2, 3: welded to 6, their colour purple."""
    glb = Glb({"scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
               "materials": [{"pbrMetallicRoughness": {"baseColorFactor": c}} for c in ([1, 0, 0, 1], [0, 0, 1, 1])]})
    left, right = STRIP_V[:4], STRIP_V[2:]
    glb.doc["meshes"] = [{"primitives": [
        {"attributes": {"POSITION": glb.add(left, "VEC3")}, "material": 0,
         "indices": glb.add(STRIP_F[:2].ravel(), "SCALAR", "<u4")},
        {"attributes": {"POSITION": glb.add(right, "VEC3")}, "material": 1,
         "indices": glb.add((STRIP_F[2:] - 2).ravel(), "SCALAR", "<u4")}]}]
    add_animation(glb, "Still", 0, "translation", [0.0], [[0.0, 0, 0]], "VEC3")
    path = glb.write(tmp_path / "two.glb")
    split = bake_animation(path, weld=False)
    assert split.vertices.shape == (1, 8, 3) and split.faces.tolist() == [[0, 2, 1], [1, 2, 3], [4, 6, 5], [5, 6, 7]]
    baked = bake_animation(path)
    np.testing.assert_array_equal(baked.vertices[0], STRIP_V)
    np.testing.assert_array_equal(baked.faces, STRIP_F)
    np.testing.assert_allclose(baked.colors, [[1, 0, 0], [1, 0, 0], [0.5, 0, 0.5], [0.5, 0, 0.5], [0, 0, 1], [0, 0, 1]])


TEXELS = np.array([[[255, 0, 0], [0, 255, 0]], [[0, 0, 255], [128, 128, 128]]], dtype=np.uint8)


def test_base_colour_texture_sampled_bilinearly_in_linear_space(tmp_path):
    """A 2x2 PNG times baseColorFactor (0.5, 1, 1): texel centres exact, midpoints the mean of linear texels."""
    png = bytes_io.BytesIO()
    Image.fromarray(TEXELS).save(png, format="PNG")
    uv = np.array([[0.25, 0.25], [0.75, 0.25], [0.25, 0.75], [0.75, 0.75], [0.5, 0.25], [0.5, 0.5]])
    glb = Glb({"scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
               "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [0.5, 1, 1, 1],
                                                       "baseColorTexture": {"index": 0}}}],
               "textures": [{"source": 0, "sampler": 0}], "samplers": [{"wrapS": 33071, "wrapT": 33071}]})
    glb.doc["images"] = [{"bufferView": glb.view(png.getvalue()), "mimeType": "image/png"}]
    attrs = {"POSITION": glb.add(STRIP_V, "VEC3"), "TEXCOORD_0": glb.add(uv, "VEC2")}
    glb.doc["meshes"] = [{"primitives": [{"attributes": attrs, "material": 0,
                                          "indices": glb.add(STRIP_F.ravel(), "SCALAR", "<u4")}]}]
    add_animation(glb, "Still", 0, "translation", [0.0], [[0.0, 0, 0]], "VEC3")
    colors = bake_animation(glb.write(tmp_path / "tex.glb")).colors
    grey = float(srgb_to_linear(128 / 255))
    expected = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [grey] * 3, [0.5, 0.5, 0],
                         [0.25 + grey / 4, 0.25 + grey / 4, 0.25 + grey / 4]]) * [0.5, 1, 1]
    np.testing.assert_allclose(colors, expected, rtol=1e-6)


def test_sample_texture_wrap_modes():
    """At u = 0 (between texel columns -1 and 0): clamp -> column 0, repeat -> the mean with column 1."""
    texels = TEXELS / 255.0
    uv = [[0.0, 0.25], [1.25, 0.25], [-0.25, 0.25]]
    np.testing.assert_allclose(sample_texture(texels, uv, ("clamp", "clamp")), [[1, 0, 0], [0, 1, 0], [1, 0, 0]])
    np.testing.assert_allclose(sample_texture(texels, uv, ("repeat", "repeat")),
                               [[0.5, 0.5, 0], [1, 0, 0], [0, 1, 0]])
    np.testing.assert_allclose(sample_texture(texels, uv, ("mirror", "mirror")), [[1, 0, 0], [0, 1, 0], [1, 0, 0]])
    assert value_error(sample_texture, texels, [[0.5, 0.5, 0.5]]) == (
        "sample_texture(): expected uv of shape (k, 2), got shape (1, 3)")
    assert value_error(sample_texture, texels[0], [[0.5, 0.5]]) == (
        "sample_texture(): expected texels of shape (H, W, C), got shape (2, 3)")
    assert value_error(sample_texture, texels, [[0.5, 0.5]], ("wrap", "clamp")) == (
        "sample_texture(): expected wrap modes from ('repeat', 'clamp', 'mirror'), got ('wrap', 'clamp')")


# ---------------------------------------------------------------- the Fox


@pytest.fixture(scope="module")
def fox_walk():
    return bake_animation(FOX, "Walk", frames=24)


def test_fox_walk_reproduces_the_shared_npz(fox_walk):
    """fox_walk_24f.npz is Walk at t = k T / 24, k < 24 (T = 0.70833 s, 33.9 fps), welded in another order.

    The vertex order is matched on frame 0 (each npz vertex has one baked vertex within 1e-5); then all 24
    frames agree to 1e-4 (measured 5.0e-5 on a fox 170 units long: a few float32 ulps of the npz's
    coordinates, which are stored as float32), and the triangles are the same, corners in the same
    cyclic order.
    """
    with np.load(FOX_NPZ) as data:
        target, faces = data["vertices"].astype(np.float64), data["faces"]
    assert fox_walk.vertices.shape == target.shape == (24, 290, 3)
    d2 = ((target[0][:, None] - fox_walk.vertices[0][None]) ** 2).sum(-1)
    match = np.argmin(d2, axis=1)
    assert len(np.unique(match)) == 290 and np.sqrt(d2.min(axis=1)).max() < 1e-5
    np.testing.assert_allclose(fox_walk.vertices[:, match], target, rtol=0, atol=1e-4)

    def cyclic(F):
        return sorted(tuple(np.roll(f, -int(np.argmin(f)))) for f in F.tolist())

    assert cyclic(match[faces]) == cyclic(fox_walk.faces)
    np.testing.assert_allclose(fox_walk.fps, 24 / 0.7083333134651184)


def test_fox_frame_counts_and_names():
    """Durations 3.4167, 0.70833 (17/24 in float32) and 1.1583 s at 24 fps: 83, 18 and 28 frames, start included."""
    assert animation_names(FOX) == ["Survey", "Walk", "Run"]
    for name, count in (("Survey", 83), ("Walk", 18), ("Run", 28)):
        baked = bake_animation(FOX, name)
        assert len(baked.vertices) == count and baked.animation == name
    np.testing.assert_allclose(baked.times[-1], 27 / 24)
    assert baked.names[0] == "Fox.glb[Run#0@0.000s]"
    assert bake_animation(FOX).animation == "Survey"                       # default: the first


def test_fox_welded_is_one_closed_manifold(fox_walk):
    """1728 seam-split vertices weld to 290: every frame a closed genus-0 manifold, one component."""
    assert fox_walk.faces.shape == (576, 3) and fox_walk.faces.dtype == np.int64
    with warnings.catch_warnings():
        warnings.simplefilter("error")                          # no unreferenced vertex dropped
        for V in fox_walk.vertices[::6]:
            validate_mesh(V, fox_walk.faces)
    assert euler_characteristic(290, fox_walk.faces) == (2, 0)
    assert connected_components(290, fox_walk.faces)[0] == 1


def test_fox_unwelded_keeps_the_file_vertices_and_seams_move_together(fox_walk):
    split = bake_animation(FOX, "Walk", frames=24, weld=False)
    assert split.vertices.shape == (24, 1728, 3) and split.colors.shape == (1728, 3)
    np.testing.assert_array_equal(split.faces, np.arange(1728).reshape(576, 3))   # no indices: a triangle list
    welded = split.vertices[:, np.unique(split.vertices[0], axis=0, return_index=True)[1]]
    np.testing.assert_array_equal(np.sort(welded[:, :, 0], 1), np.sort(fox_walk.vertices[:, :, 0], 1))


def test_fox_rest_pose_against_trimesh(tmp_path):
    """The Fox's joint nodes hold its bind pose: a one-key STEP channel at the rest rotation gives the
    rest positions, as trimesh reads them: to 1e-4 on 170 units (measured 1.0e-5; the file's bind
    matrices and node rotations are float32, their product the identity to 8e-6)."""
    glb = Glb.read(FOX)
    node = glb.doc["skins"][0]["joints"][2]
    add_animation(glb, "Rest", node, "rotation", [0.0], [glb.doc["nodes"][node]["rotation"]], "VEC4", "STEP")
    baked = bake_animation(glb.write(tmp_path / "rest.glb"), "Rest")
    V, F = io.read_mesh(FOX)
    np.testing.assert_allclose(baked.vertices[0], V, rtol=0, atol=1e-4)
    np.testing.assert_array_equal(baked.faces, F)


def test_fox_texture_colours(fox_walk):
    C = fox_walk.colors
    assert C.shape == (290, 3) and C.dtype == np.float64
    assert C.min() >= 0 and C.max() <= 1 and C.std(axis=0).min() > 0.05
    assert len(np.unique(C.round(3), axis=0)) > 20


def test_read_frames_bakes_an_animation():
    frames = io.read_frames([FOX], animation="Walk", fps=24.0)
    frame = frames[17]()
    assert len(frames) == 18 and frame.name == "Fox.glb[Walk#17@0.708s]"
    assert frame.vertices.shape == (290, 3) and frame.faces.shape == (576, 3) and frame.normals is None
    assert frames[0].correspondence


# ---------------------------------------------------------------- refusals


def test_not_gltf_and_missing_files(tmp_path):
    (tmp_path / "t.obj").write_text("v 0 0 0\nv 1 0 0\n")
    for call in (bake_animation, animation_names):
        assert value_error(call, tmp_path / "t.obj") == (
            f"{call.__name__}(): expected a glTF 2.0 file (binary .glb or JSON .gltf) '{tmp_path / 't.obj'}', "
            "got a file that starts with b'v 0 0 0\\nv 1 '")
    (tmp_path / "old.gltf").write_text('{"asset": {"version": "1.0"}}')
    assert value_error(bake_animation, tmp_path / "old.gltf") == (
        f"bake_animation(): expected a glTF 2.0 file (binary .glb or JSON .gltf) '{tmp_path / 'old.gltf'}', "
        "got JSON without asset.version 2.x")
    assert value_error(bake_animation, tmp_path / "none.glb") == (
        f"bake_animation(): expected a readable file '{tmp_path / 'none.glb'}', "
        "got FileNotFoundError: No such file or directory")


def test_no_animation_and_unknown_animation(tmp_path):
    glb = Glb({"scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}]})
    glb.doc["meshes"] = [{"primitives": [{"attributes": {"POSITION": glb.add(STRIP_V, "VEC3")},
                                          "indices": glb.add(STRIP_F.ravel(), "SCALAR", "<u4")}]}]
    path = glb.write(tmp_path / "still.glb")
    assert animation_names(path) == []
    assert value_error(bake_animation, path) == (
        f"bake_animation(): expected an animation in '{path}', got none (the file has no 'animations')")
    assert value_error(bake_animation, FOX, "Jump") == (
        f"bake_animation(): expected an animation named one of ['Survey', 'Walk', 'Run'] in '{FOX}', got 'Jump'")
    message = "bake_animation(): expected an animation name (str) or None, got int 1"
    with pytest.raises(TypeError, match=exactly(message)):
        bake_animation(FOX, 1)


@pytest.mark.parametrize("fps", [0, -24.0, float("nan"), float("inf")])
def test_fps_must_be_finite_and_positive(fps):
    assert value_error(bake_animation, FOX, "Walk", fps) == (
        f"bake_animation(): expected fps finite and > 0, got {float(fps)!r}")


def test_fps_and_frames_types():
    with pytest.raises(TypeError, match=exactly("bake_animation(): expected fps as a number, got str '24'")):
        bake_animation(FOX, "Walk", "24")
    with pytest.raises(TypeError, match=exactly("bake_animation(): expected frames as an int or None, got float 24.0")):
        bake_animation(FOX, "Walk", frames=24.0)
    assert value_error(bake_animation, FOX, "Walk", frames=0) == "bake_animation(): expected frames >= 1, got 0"


def test_file_without_a_mesh(tmp_path):
    glb = Glb({"scenes": [{"nodes": [0]}], "nodes": [{"name": "empty"}]})
    add_animation(glb, "Move", 0, "translation", [0.0, 1.0], [[0.0, 0, 0], [1.0, 0, 0]], "VEC3")
    path = glb.write(tmp_path / "empty.glb")
    assert value_error(bake_animation, path) == (
        f"bake_animation(): expected a mesh in the scene of '{path}', got no node with a mesh")


def test_malformed_files(tmp_path):
    glb = Glb.read(skinned_strip(tmp_path))
    glb.doc["animations"][0]["samplers"][0]["input"] = 99
    assert value_error(bake_animation, glb.write(tmp_path / "bad.glb"), "Bend") == (
        f"bake_animation(): expected a valid glTF 2.0 file '{tmp_path / 'bad.glb'}', "
        "got IndexError: list index out of range")
    glb.doc["animations"][0]["samplers"][0]["input"] = glb.doc["animations"][1]["samplers"][0]["input"]
    glb.doc["animations"][0]["samplers"][0]["interpolation"] = "SMOOTH"
    assert value_error(bake_animation, glb.write(tmp_path / "bad.glb"), "Bend") == (
        f"bake_animation(): expected sampler interpolation LINEAR, STEP or CUBICSPLINE in '{tmp_path / 'bad.glb'}', "
        "got 'SMOOTH'")
    glb.doc["animations"][0]["samplers"][0]["interpolation"] = "LINEAR"
    glb.doc["meshes"][0]["primitives"][0]["mode"] = 1
    assert value_error(bake_animation, glb.write(tmp_path / "lines.glb"), "Bend") == (
        f"bake_animation(): expected triangle primitives (mode 4) in '{tmp_path / 'lines.glb'}', got mode 1 in mesh 0")


def test_skin_weights_that_sum_to_zero(tmp_path):
    path = skinned_strip(tmp_path, ("<f4", False, 0.0))
    assert value_error(bake_animation, path) == (
        f"bake_animation(): expected skin weights with a positive sum at every vertex in '{path}', "
        "got vertex 0 with weights [0.0, 0.0, 0.0, 0.0] (6 such vertices)")


def _drop_joints(doc):
    del doc["meshes"][0]["primitives"][0]["attributes"]["JOINTS_0"]


@pytest.mark.parametrize(("edit", "what", "got"), [
    (lambda doc: doc["nodes"][2].update(children=[1]), "a node hierarchy without cycles", "a cycle through node 1"),
    (lambda doc: doc["accessors"][2].update(sparse={"count": 1}), "accessors without sparse storage",
     "sparse accessor 2"),
    (lambda doc: doc["skins"][0].update(joints=[1]), "joint indices below the skin's 1 joints",
     "vertex 2 with joints [0, 1, 0, 0]"),
    (_drop_joints, "JOINTS_0 and WEIGHTS_0 on every skinned primitive", "attributes ['POSITION', 'WEIGHTS_0']"),
], ids=["cycle", "sparse", "joint-index", "no-joints"])
def test_malformed_scenes_and_skins(tmp_path, edit, what, got):
    glb = Glb.read(skinned_strip(tmp_path))
    edit(glb.doc)
    path = glb.write(tmp_path / "bad.glb")
    assert value_error(bake_animation, path) == f"bake_animation(): expected {what} in '{path}', got {got}"


def test_triangle_index_out_of_range(tmp_path):
    glb = Glb.read(skinned_strip(tmp_path))
    glb.doc["meshes"][0]["primitives"][0]["indices"] = glb.add([0, 1, 9], "SCALAR", "<u4")
    path = glb.write(tmp_path / "bad.glb")
    assert value_error(bake_animation, path) == (
        f"bake_animation(): expected triangle indices below the 6 vertices of mesh 0 in '{path}', got index 9")


def test_one_pose_animation_and_unnamed_animations(tmp_path):
    glb = Glb.read(skinned_strip(tmp_path))
    add_animation(glb, "Still", 2, "rotation", [0.0], [z_quaternion(0)], "VEC4")
    del glb.doc["animations"][1]["name"]
    path = glb.write(tmp_path / "still.glb")
    assert animation_names(path) == ["Bend", "animation_1", "Still"]
    assert len(bake_animation(path, "Still", fps=24).times) == len(bake_animation(path, "Still", frames=1).times) == 1
    assert value_error(bake_animation, path, "Still", frames=3) == (
        "bake_animation(): expected an animation longer than 0 s for frames = 3, got 'Still', one pose at t = 0")
