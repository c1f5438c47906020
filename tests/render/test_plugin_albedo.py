"""Per-control-vertex albedo of ``loop_subdiv``: carried by the limit operator, differentiable, in PLY files."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mi_loop import datasets, io, plugin
from mi_loop.subdiv.limit import limit_matrix
from mi_loop.subdiv.tessellation import tessellate

from helpers import exactly

LEVEL = 2


@pytest.fixture(scope="module")
def blob():
    return datasets.blob()


def colors(shape) -> np.ndarray:
    return np.asarray(mi.traverse(shape)[plugin.COLOR_ATTRIBUTE], dtype=np.float64).reshape(-1, 3)


def test_an_affine_albedo_is_the_same_affine_function_of_the_limit_points(blob):
    """Loop limits reproduce affine functions: c_i = A V_i + b at the control vertices gives A P + b on the surface."""
    V, F = blob
    A = np.array([[0.2, -0.1, 0.05], [0.0, 0.15, 0.1], [-0.1, 0.05, 0.2]])
    b = np.array([0.5, 0.45, 0.55])
    albedo = V @ A.T + b
    assert 0 <= albedo.min() and albedo.max() <= 1
    shape = plugin.create(V, F, level=LEVEL, albedo=albedo)
    P, _, _ = plugin.mesh_arrays(shape)
    np.testing.assert_allclose(colors(shape), P @ A.T + b, rtol=0, atol=2e-6)


def test_vertex_colors_are_the_limit_matrix_applied_to_the_albedo(blob):
    V, F = blob
    albedo = np.random.default_rng(0).uniform(0, 1, size=V.shape)
    shape = plugin.create(V, F, level=LEVEL, albedo=albedo)
    face_ids, uv, _ = tessellate(F, LEVEL)
    W = limit_matrix(F, len(V), face_ids, uv)
    expected = W @ albedo
    np.testing.assert_allclose(colors(shape), expected, rtol=0, atol=2e-6)
    assert expected.min() >= 0 and expected.max() <= 1      # non-negative weights: a convex combination


def test_updating_control_albedo_recolours_without_moving_the_geometry(blob):
    V, F = blob
    shape = plugin.create(V, F, level=LEVEL, albedo=np.full(V.shape, 0.3))
    P_before = plugin.mesh_arrays(shape)[0]
    params = mi.traverse(shape)
    params["control_albedo"] = mi.Float(np.full(V.size, 0.7, dtype=np.float32))
    params.update()
    np.testing.assert_allclose(colors(shape), 0.7, atol=1e-6)
    np.testing.assert_array_equal(plugin.mesh_arrays(shape)[0], P_before)


def test_a_shape_without_albedo_exposes_none(blob):
    shape = plugin.create(*blob, level=1)
    assert not shape.has_albedo
    assert "control_albedo" not in mi.traverse(shape).keys()


def test_albedo_gradient_matches_finite_differences(blob, jit_variant):
    """d loss / d control_albedo: AD vs central differences (the render is linear in the albedo).

    Scene: the blob at level 1, 24x24 pixels, constant environment, ``direct_projective``,
    64 spp with one seed for every render, loss = mean of (image - 0.4)^2. With a
    shared seed the finite differences see the same paths, so they agree to float32
    round-off; tolerance 2 %.
    """
    V, F = blob
    shape = plugin.create(V, F, level=1, albedo=np.full(V.shape, 0.5))
    scene = mi.load_dict({
        "type": "scene", "shape": shape, "light": {"type": "constant"},
        "integrator": {"type": "direct_projective", "sppi": 0},
        "sensor": {"type": "perspective", "fov": 40,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0.5, 4], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 24, "height": 24, "rfilter": {"type": "box"}}}})
    params = mi.traverse(scene)
    key = "shape.control_albedo"
    params.keep([key])
    c0 = np.full(V.size, 0.5)

    def loss(c, grad=False):
        params[key] = mi.Float(np.asarray(c, dtype=np.float32))
        if grad:
            dr.enable_grad(params[key])
        params.update()
        image = mi.render(scene, params, spp=64, seed=5)
        return dr.mean(dr.square(image - 0.4), axis=None).array

    value = loss(c0, grad=True)
    dr.backward(value)
    gradient = np.asarray(dr.grad(params[key]), dtype=np.float64)
    rng = np.random.default_rng(2)
    eps = 0.05
    for direction in (np.ones(V.size), rng.normal(size=V.size)):
        d = direction / np.linalg.norm(direction)
        with dr.suspend_grad():
            fd = (loss(c0 + eps * d)[0] - loss(c0 - eps * d)[0]) / (2 * eps)
        assert abs(fd) > 1e-4
        np.testing.assert_allclose(gradient @ d, fd, rtol=0.02)


def test_ply_vertex_colours_round_trip_into_the_plugin(tmp_path, blob, jit_variant):
    V, F = blob
    albedo = np.random.default_rng(3).uniform(0, 1, size=V.shape).astype(np.float32)
    path = io.write_ply(tmp_path / "cage.ply", V, F, colors=albedo)
    np.testing.assert_array_equal(io.read_vertex_colors(path), albedo)
    scene = mi.load_dict({"type": "scene", "s": {"type": "loop_subdiv", "filename": str(path), "level": 1,
                                                 "bsdf": plugin.albedo_bsdf()}})
    shape = scene.shapes()[0]
    assert shape.has_albedo
    face_ids, uv, _ = tessellate(F, 1)
    np.testing.assert_allclose(colors(shape), limit_matrix(F, len(V), face_ids, uv) @ albedo, atol=2e-6)


def test_ply_display_colours_are_srgb_encoded(tmp_path, blob):
    V, F = blob
    albedo = np.full(V.shape, 0.2)
    path = io.write_ply(tmp_path / "cage.ply", V, F, colors=albedo)
    ply = io.ply.read_ply(path)["vertex"]
    assert int(ply["red"][0]) == round(255 * (1.055 * 0.2 ** (1 / 2.4) - 0.055))   # 124
    assert io.read_vertex_colors(tmp_path / "cage.obj") is None


def test_plain_rgb_ply_colours_are_decoded_from_srgb(tmp_path):
    path = tmp_path / "rgb.ply"
    path.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                    "property uchar red\nproperty uchar green\nproperty uchar blue\nelement face 1\n"
                    "property list uchar int vertex_indices\nend_header\n"
                    "0 0 0 255 0 0\n1 0 0 0 255 0\n0 1 0 124 124 124\n3 0 1 2\n")
    C = io.read_vertex_colors(path)
    np.testing.assert_allclose(C[:2], np.eye(3)[:2], atol=1e-7)
    np.testing.assert_allclose(C[2], 0.2, atol=2e-3)


@pytest.mark.parametrize("albedo, message", [
    (np.full((5, 3), 0.5), "loop_subdiv: expected albedo of shape ({n}, 3) (one RGB per control vertex), "
                           "got shape (5, 3)"),
    ("bad", "loop_subdiv: expected albedo in [0, 1], got [1.5, 0.5, 0.5] at control vertex 7"),
])
def test_bad_albedo_is_refused(blob, albedo, message):
    V, F = blob
    if isinstance(albedo, str):
        albedo = np.full(V.shape, 0.5)
        albedo[7, 0] = 1.5
    with pytest.raises(ValueError, match=exactly(message.format(n=len(V)))):
        plugin.create(V, F, level=1, albedo=albedo)


def test_write_ply_refuses_colours_of_the_wrong_shape(tmp_path, blob):
    V, F = blob
    with pytest.raises(ValueError, match=exactly(f"write_ply(): expected finite colors of shape ({len(V)}, 3), "
                                                 "got shape (2, 3)")):
        io.write_ply(tmp_path / "x.ply", V, F, colors=np.zeros((2, 3)))
