"""Tests of the Mitsuba shape plugin ``loop_subdiv`` (mi_loop.render.plugin)."""
from __future__ import annotations

import re

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import mi_loop
from mi_loop import datasets, io, plugin
from mi_loop.render import scene as render
from mi_loop.subdiv.limit import limit_matrix

from helpers import flat

LEVEL = 2


@pytest.fixture(scope="module")
def blob():
    return datasets.blob()


@pytest.fixture(scope="module")
def blob_file(tmp_path_factory, blob):
    path = tmp_path_factory.mktemp("plugin") / "blob.ply"
    io.write_ply(path, *blob)
    return path


def reference(V, F, level, creases=None, faces=None, **model):
    """Limit points, unit limit normals and triangles of the tessellation, in float64 with SciPy."""
    face_ids, uv, F_tess = mi_loop.tessellate(F, level, faces)
    W, Wu, Wv = (limit_matrix(F, len(V), face_ids, uv, creases, d, **model) for d in (None, "u", "v"))
    N = np.cross(Wu @ V, Wv @ V)
    return W @ V, N / np.linalg.norm(N, axis=1, keepdims=True), np.asarray(F_tess)


def operator_arrays(V, F, level, x=None, creases=None):
    """Positions and normals from a LimitOperator built independently of the plugin."""
    face_ids, uv, _ = mi_loop.tessellate(F, level)
    op = mi_loop.LimitOperator(F, len(V), face_ids, uv, creases=creases)
    x = flat(V) if x is None else x
    return (np.asarray(dr.ravel(op.positions(x))).reshape(-1, 3),
            np.asarray(dr.ravel(op.normals(x))).reshape(-1, 3))


def assert_matches_limit(shape, V, F, level, creases=None):
    P, N, F_tess = plugin.mesh_arrays(shape)
    P_op, N_op = operator_arrays(V, F, level, creases=creases)
    np.testing.assert_allclose(P, P_op, rtol=0, atol=1e-6)
    np.testing.assert_allclose(N, N_op, rtol=0, atol=1e-6)
    P_ref, N_ref, F_ref = reference(V, F, level, creases)
    np.testing.assert_array_equal(F_tess, F_ref)
    np.testing.assert_allclose(P, P_ref, rtol=0, atol=2e-6)
    np.testing.assert_allclose(N, N_ref, rtol=0, atol=2e-5)


def test_load_dict_gives_exact_limit_surface(blob, blob_file, jit_variant):
    V, F = blob
    shape = mi.load_dict({"type": "loop_subdiv", "filename": str(blob_file), "level": LEVEL})
    assert shape.face_count() == len(F) * 4 ** LEVEL
    assert shape.has_vertex_normals()
    assert_matches_limit(shape, V, F, LEVEL)


def test_xml_scene_loads_its_generated_control_mesh(scenes_dir):
    scene = mi.load_file(str(scenes_dir / "blob.xml"), spp=4, res=16, level=1)
    shape = next(s for s in scene.shapes() if s.id() == "blob")
    V, F = io.read_mesh(scenes_dir / "blob.ply")
    assert_matches_limit(shape, V, F, 1)


@pytest.mark.parametrize("name", ["blob", "torus"])
def test_scene_control_meshes_are_the_package_datasets(scenes_dir, name):
    V, F = io.read_mesh(scenes_dir / f"{name}.ply")
    V_ds, F_ds = datasets.control_mesh(name)
    np.testing.assert_array_equal(V, V_ds)
    np.testing.assert_array_equal(F, F_ds)


def test_crease_scene_loads_with_creases(scenes_dir):
    scene = mi.load_file(str(scenes_dir / "torus_crease.xml"), level=1)
    shape = next(s for s in scene.shapes() if s.id() == "torus")
    V, F = io.read_mesh(scenes_dir / "torus.ply")
    creases = np.array([[8 * i, 8 * ((i + 1) % 12)] for i in range(12)])
    assert_matches_limit(shape, V, F, 1, creases=creases)
    P_smooth, _, _ = reference(V, F, 1)
    assert np.abs(plugin.mesh_arrays(shape)[0] - P_smooth).max() > 1e-3   # the crease changes the surface


def test_crease_model_properties(blob, blob_file):
    """Sharpness in ``creases``, ``corners``, ``crease_method``: the limit surface of the same crease model."""
    V, F = blob
    E = np.array([F[0, :2], F[0, 1:], F[5, :2]])
    shape = mi.load_dict({"type": "loop_subdiv", "filename": str(blob_file), "level": 1,
                          "creases": f"{E[0, 0]} {E[0, 1]} 2.5, {E[1, 0]} {E[1, 1]} 1.5; {E[2, 0]} {E[2, 1]}",
                          "corners": f"{F[9, 0]} 1.5, {F[12, 1]}", "crease_method": "chaikin"})
    model = dict(creases=(E, [2.5, 1.5, np.inf]), corners=([F[9, 0], F[12, 1]], [1.5, np.inf]),
                 crease_method="chaikin")
    P, N, F_tess = plugin.mesh_arrays(shape)
    P_ref, N_ref, F_ref = reference(V, F, 1, **model)
    np.testing.assert_array_equal(F_tess, F_ref)
    np.testing.assert_allclose(P, P_ref, rtol=0, atol=2e-6)
    np.testing.assert_allclose(N, N_ref, rtol=0, atol=2e-5)
    P_uniform, _, _ = reference(V, F, 1, **{**model, "crease_method": "uniform"})
    assert np.abs(P - P_uniform).max() > 1e-4            # two semi-sharp edges meet at F[0, 1]: Chaikin matters


def test_creases_of_a_ply_control_mesh_are_used(tmp_path, blob):
    """A control.ply with an edge element (as mi-loop fit writes it) renders with its creases;
    the ``creases`` property overrides them."""
    V, F = blob
    E = np.array([F[0, :2], F[0, 1:]])
    io.write_ply(tmp_path / "c.ply", V, F, creases=(E, [np.inf, 1.5]))
    shape = mi.load_dict({"type": "loop_subdiv", "filename": str(tmp_path / "c.ply"), "level": 1})
    P_ref, _, _ = reference(V, F, 1, creases=(E, [np.inf, 1.5]))
    np.testing.assert_allclose(plugin.mesh_arrays(shape)[0], P_ref, rtol=0, atol=2e-6)
    plain = mi.load_dict({"type": "loop_subdiv", "filename": str(tmp_path / "c.ply"), "level": 1, "creases": ""})
    np.testing.assert_allclose(plugin.mesh_arrays(plain)[0], reference(V, F, 1)[0], rtol=0, atol=2e-6)
    assert np.abs(P_ref - reference(V, F, 1)[0]).max() > 1e-3


def test_boundary_none_leaves_the_holes_out(jit_variant):
    from mi_loop.mesh.topology import sharp_topology

    from meshes import grid

    mesh = grid(6, 5)
    hole = sharp_topology(mesh.F, len(mesh.V), "test", boundary="none").hole
    shape = plugin.create(mesh.V, mesh.F, level=1, boundary="none")
    assert shape.face_count() == 4 * int((~hole).sum()) < 4 * len(mesh.F)
    P, N, F_tess = plugin.mesh_arrays(shape)
    P_ref, N_ref, F_ref = reference(mesh.V, mesh.F, 1, faces=np.flatnonzero(~hole), boundary="none")
    np.testing.assert_array_equal(F_tess, F_ref)
    np.testing.assert_allclose(P, P_ref, rtol=0, atol=2e-6)
    with pytest.raises(ValueError, match=re.escape("loop_subdiv: every one of the 10 control faces is a hole under "
                                                   "boundary 'none'")):
        plugin.create(mesh.V[:12], mesh.F[:10], level=1, boundary="none")     # one strip: all on the boundary


def test_xml_filename_is_relative_to_the_xml(tmp_path, blob):
    (tmp_path / "meshes").mkdir()
    io.write_ply(tmp_path / "meshes" / "c.ply", *blob)
    (tmp_path / "s.xml").write_text(
        '<scene version="3.0.0"><shape type="loop_subdiv" id="s">'
        '<string name="filename" value="meshes/c.ply"/><integer name="level" value="1"/>'
        '<transform name="to_world"><translate value="1, 2, 3"/></transform>'
        "</shape></scene>")
    scene = mi.load_file(str(tmp_path / "s.xml"))
    P, N, _ = plugin.mesh_arrays(scene.shapes()[0])
    P_op, N_op = operator_arrays(*blob, 1)
    np.testing.assert_allclose(P, P_op + [1, 2, 3], rtol=0, atol=1e-5)   # to_world moves the control points
    np.testing.assert_allclose(N, N_op, rtol=0, atol=1e-5)


def test_traverse_exposes_differentiable_control_points(blob, blob_file):
    V, _ = blob
    params = mi.traverse(mi.load_dict({"type": "loop_subdiv", "filename": str(blob_file), "level": 1}))
    assert "control_points" in params
    x = params["control_points"]
    assert isinstance(x, mi.Float) and dr.width(x) == 3 * len(V)
    np.testing.assert_array_equal(np.asarray(x), V.astype(np.float32).ravel())
    flags = params.flags("control_points")
    assert not flags & int(mi.ParamFlags.NonDifferentiable)
    assert flags & int(mi.ParamFlags.Discontinuous)       # moves silhouettes: projective integrators


def test_update_moves_geometry_as_predicted(blob):
    V, F = blob
    shape = plugin.create(V, F, level=LEVEL)
    params = mi.traverse(shape)
    x = mi.Float(params["control_points"])
    P0, N0, _ = plugin.mesh_arrays(shape)

    params["control_points"] = x + mi.Float(np.tile([0.5, -1.0, 2.0], len(V)).astype(np.float32))
    params.update()
    P1, N1, _ = plugin.mesh_arrays(shape)
    np.testing.assert_allclose(P1, P0 + [0.5, -1.0, 2.0], rtol=0, atol=1e-5)   # affine invariance
    np.testing.assert_allclose(N1, N0, rtol=0, atol=1e-5)
    np.testing.assert_allclose(np.array(shape.bbox().min), P1.min(axis=0), atol=1e-6)

    delta = np.random.default_rng(0).normal(scale=0.05, size=V.shape)
    x_new = flat(V + delta)
    params["control_points"] = x_new
    params.update()
    P2, N2, _ = plugin.mesh_arrays(shape)
    P_ref, N_ref, _ = reference(V + delta, F, LEVEL)
    np.testing.assert_allclose(P2, P_ref, rtol=0, atol=2e-6)                     # Q = W (V + delta)
    np.testing.assert_allclose(N2, N_ref, rtol=0, atol=2e-5)
    assert np.abs(P2 - P0).max() > 0.01


def test_update_rejects_wrong_length(blob):
    shape = plugin.create(*blob, level=1)
    params = mi.traverse(shape)
    params["control_points"] = mi.Float(np.zeros(9, dtype=np.float32))
    with pytest.raises(ValueError, match=r"3 \* 42 values, got 9"):
        params.update()


@pytest.mark.parametrize("props, message", [
    ({"level": 1}, "missing the 'filename' property"),
    ({"filename": "/nonexistent/c.ply"}, "no such file"),
    ({"filename": "FILE", "level": -1}, "expected an integer level >= 0, got -1"),
    ({"filename": "FILE", "creases": "0 1, 2"}, "creases entry 1 is '2'"),
    ({"filename": "FILE", "corners": "0 x"}, "corners entry 0 is '0 x'"),
    ({"filename": "FILE", "corners": "99"}, re.escape("loop_subdiv(): expected corner vertices in [0, 42), "
                                                      "got vertex 99 at corner 0")),
    ({"filename": "FILE", "boundary": "corner"}, re.escape("loop_subdiv(): expected boundary one of "
                                                           "'edge_and_corner', 'edge_only', 'none', got 'corner'")),
    ({"filename": "FILE", "crease_method": "x"}, "expected crease_method one of 'uniform', 'chaikin', got 'x'"),
])
def test_bad_properties_are_reported(blob_file, props, message):
    props = {k: (str(blob_file) if v == "FILE" else v) for k, v in props.items()}
    with pytest.raises(RuntimeError, match=message):
        mi.load_dict({"type": "loop_subdiv", **props})


def test_parse_creases():
    E, s = plugin.parse_crease_text("0 1, 1 2 2.5;2 3 inf, 3 4 1e1 ")
    np.testing.assert_array_equal(E, [[0, 1], [1, 2], [2, 3], [3, 4]])
    np.testing.assert_array_equal(s, [np.inf, 2.5, np.inf, 10.0])
    assert plugin.parse_crease_text("") is None
    with pytest.raises(ValueError, match=re.escape("loop_subdiv: creases entry 0 is '0 x', expected two vertex "
                                                   "indices and an optional sharpness such as '0 1' or '0 1 2.5'")):
        plugin.parse_crease_text("0 x")
    with pytest.raises(ValueError, match="creases entry 1 is '1 2 -3'"):
        plugin.parse_crease_text("0 1, 1 2 -3")


def test_parse_corners():
    ids, s = plugin.parse_corner_text("4, 7 1.5; 9 .25")
    np.testing.assert_array_equal(ids, [4, 7, 9])
    np.testing.assert_array_equal(s, [np.inf, 1.5, 0.25])
    assert plugin.parse_corner_text(" ") is None
    with pytest.raises(ValueError, match=re.escape("loop_subdiv: corners entry 1 is '1 2 3', expected a vertex "
                                                   "index and an optional sharpness such as '4' or '4 1.5'")):
        plugin.parse_corner_text("0, 1 2 3")


def test_render_gradient_matches_finite_differences(blob, jit_variant):
    """d loss / d control_points along two directions: AD vs central differences.

    Scene: the blob at level 2 in a constant environment, 32x32 pixels,
    ``direct_projective`` (silhouette and shading gradients), 256 spp, seed 3
    shared by all renders; loss = mean pixel value. Measured: AD and central
    differences (eps = 1e-2) agree within 2-3 %; tolerance 10 % (Monte Carlo).
    """
    V, F = blob
    shape = plugin.create(V, F, level=2)
    scene_desc = render.scene_dict(shape, resolution=32, sample_border=True,
                                   integrator={"type": "direct_projective"})
    del scene_desc["key_light"]
    scene = mi.load_dict(scene_desc)
    params = mi.traverse(scene)
    key = "shape.control_points"
    x0 = mi.Float(params[key])

    def loss(x, grad=False):
        params[key] = mi.Float(x)
        if grad:
            dr.enable_grad(params[key])
        params.update()
        with dr.suspend_grad(when=not grad):
            value = dr.mean(render.render_view(scene, spp=256, seed=3, params=params), axis=None).array
        return value

    dr.backward(loss(x0, grad=True))
    gradient = np.asarray(dr.grad(params[key]), dtype=np.float64)
    eps = 1e-2
    rng = np.random.default_rng(1)
    for direction in (V.ravel(), rng.normal(size=V.size)):
        d = direction * np.sqrt(len(V)) / np.linalg.norm(direction)
        d_t = mi.Float(d.astype(np.float32))
        fd = (loss(x0 + eps * d_t)[0] - loss(x0 - eps * d_t)[0]) / (2 * eps)
        ad = gradient @ d
        assert abs(fd) > 1e-3                     # the direction does change the image
        np.testing.assert_allclose(ad, fd, rtol=0.1)
