"""ARAP regulariser: rigid invariance, rotations, cotangent weights, gradients, errors."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mi_loop.energies.arap import ARAP, cotangent_weights

from helpers import as_numpy, flat, point3f
from meshes import grid, icosahedron, open_cylinder

MESHES = [icosahedron(), grid(), open_cylinder()]


def _energy_and_grad(arap, V, R=None):
    x = flat(V, grad=True)
    E = arap.energy(x, R)
    dr.backward(E)
    return float(E[0]), as_numpy(dr.grad(x))


def _energy_ref(arap, V, R):
    """float64 NumPy E(V, R), written directly from the formula."""
    e_rest = arap.V_rest[arap.I] - arap.V_rest[arap.J]
    d = (V[arap.I] - V[arap.J]) - np.einsum("kab,kb->ka", R[arap.I], e_rest)
    return np.sum(arap.w * np.sum(d * d, 1))


def _fd(fun, V, eps=1e-6):
    g = np.zeros_like(V)
    for i in range(V.shape[0]):
        for a in range(3):
            Vp, Vm = V.copy(), V.copy()
            Vp[i, a] += eps
            Vm[i, a] -= eps
            g[i, a] = (fun(Vp) - fun(Vm)) / (2 * eps)
    return g


def test_cotangent_weights_by_hand():
    # equilateral triangle: every edge is a boundary edge with cot(60 deg) / 2
    V = np.array([[0, 0, 0], [1, 0, 0], [0.5, np.sqrt(3) / 2, 0]])
    E, w = cotangent_weights(V, np.array([[0, 1, 2]]))
    np.testing.assert_array_equal(E, [[0, 1], [0, 2], [1, 2]])
    np.testing.assert_allclose(w, 0.5 / np.sqrt(3), rtol=1e-12)
    # unit square split along 0-2: sides cot(45 deg) / 2, diagonal cot(90) + cot(90) = 0 -> floor
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    E, w = cotangent_weights(V, np.array([[0, 1, 2], [0, 2, 3]]), min_weight=1e-3)
    np.testing.assert_array_equal(E, [[0, 1], [0, 2], [0, 3], [1, 2], [2, 3]])
    np.testing.assert_allclose(w, [0.5, 1e-3, 0.5, 0.5, 0.5], rtol=1e-12, atol=1e-15)
    # an obtuse pair (both opposite angles 120 deg) has a negative sum and is clamped too
    V = np.array([[-1, 0, 0], [1, 0, 0], [0, 0.3, 0], [0, -0.3, 0]])
    E, w = cotangent_weights(V, np.array([[0, 1, 2], [1, 0, 3]]), min_weight=1e-3)
    assert w[np.flatnonzero((E == [0, 1]).all(1))[0]] == 1e-3


@pytest.mark.parametrize("mesh", MESHES, ids=lambda m: m.name)
def test_rigid_motion_has_zero_energy_and_gradient(mesh):
    arap = ARAP(mesh.V, mesh.F)
    Rot = Rotation.random(random_state=7).as_matrix()
    V = mesh.V @ Rot.T + np.array([0.3, -1.2, 2.0])
    R = arap.rotations(V)
    np.testing.assert_allclose(R, np.broadcast_to(Rot, R.shape), atol=1e-12)
    E, g = _energy_and_grad(arap, V, R)
    scale = np.sum(arap.w * np.sum(arap.e_rest ** 2, 1))   # energy of collapsing every edge
    g_scale = np.bincount(arap.I, arap.w * np.linalg.norm(arap.e_rest, axis=1)).max()
    # float32: residual edges ~1e-7 |e| -> E ~1e-14 scale, gradient ~1e-7 g_scale
    assert abs(E) < 1e-10 * scale
    np.testing.assert_allclose(g, 0, atol=1e-5 * g_scale)


@pytest.mark.parametrize("mesh", MESHES, ids=lambda m: m.name)
def test_nonrigid_deformation_has_positive_energy(mesh):
    arap = ARAP(mesh.V, mesh.F)
    V = mesh.V * [1.2, 1.0, 0.9]
    E, _ = _energy_and_grad(arap, V)
    np.testing.assert_allclose(E, _energy_ref(arap, V, arap.rotations(V)), rtol=1e-5)
    assert E > 1e-3


def test_rotation_is_proper_when_the_best_orthogonal_map_is_a_reflection():
    mesh = icosahedron()
    arap = ARAP(mesh.V, mesh.F)
    M = np.diag([1.0, 1.0, -1.0])                          # mirror: best orthogonal map is M
    V = mesh.V @ M.T
    R = arap.rotations(V)
    np.testing.assert_allclose(np.linalg.det(R), 1, atol=1e-12)
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)

    def E_i(i, Ri):  # one-ring energy of vertex i
        k = arap.I == i
        d = (V[arap.I[k]] - V[arap.J[k]]) - arap.e_rest[k] @ Ri.T
        return np.sum(arap.w[k] * np.sum(d * d, 1))

    rng = np.random.default_rng(8)
    for i in range(len(V)):
        assert E_i(i, M) < E_i(i, R[i]) - 1e-6               # the reflection would fit better...
        for _ in range(20):                                   # ...but R is optimal on SO(3)
            Rp = Rotation.from_rotvec(1e-2 * rng.standard_normal(3)).as_matrix() @ R[i]
            assert E_i(i, R[i]) <= E_i(i, Rp) + 1e-12


@pytest.mark.parametrize("mesh", MESHES, ids=lambda m: m.name)
def test_gradient_with_fixed_rotations_matches_central_differences(mesh):
    arap = ARAP(mesh.V, mesh.F)
    V = mesh.V + 0.1 * np.random.default_rng(9).standard_normal(mesh.V.shape)
    R = Rotation.random(len(V), random_state=10).as_matrix()  # any fixed R, not only the optimum
    E, g = _energy_and_grad(arap, V, R)
    np.testing.assert_allclose(E, _energy_ref(arap, V, R), rtol=1e-5)
    fd = _fd(lambda W: _energy_ref(arap, W, R), V)            # float64, step 1e-6: error ~1e-9
    # AD in float32: error ~1e-6 relative to the largest component
    np.testing.assert_allclose(g, fd, atol=1e-4 * np.abs(fd).max())


@pytest.mark.parametrize("mesh", MESHES, ids=lambda m: m.name)
def test_envelope_gradient_matches_differences_with_recomputed_rotations(mesh):
    arap = ARAP(mesh.V, mesh.F)
    V = mesh.V + 0.1 * np.random.default_rng(11).standard_normal(mesh.V.shape)
    _, g = _energy_and_grad(arap, V, arap.rotations(V))
    # E*(V) = E(V, R*(V)) with R* recomputed (SVD) at every perturbed V, in float64
    fd = _fd(lambda W: _energy_ref(arap, W, arap.rotations(W)), V)
    np.testing.assert_allclose(g, fd, atol=1e-4 * np.abs(fd).max())
    # the test has teeth: freezing R at a wrong value changes the gradient visibly
    _, g_wrong = _energy_and_grad(arap, V, arap.rotations(mesh.V))
    assert np.abs(g_wrong - fd).max() > 1e-2 * np.abs(fd).max()


def test_energy_accepts_point3f_and_reuses_kernels():
    mesh = open_cylinder()
    arap = ARAP(mesh.V, mesh.F)
    rng = np.random.default_rng(12)

    def step(V):
        x = point3f(V)
        dr.enable_grad(x)
        E = arap.energy(x)                                    # R computed from x
        dr.backward(E)
        dr.eval(dr.grad(x))
        return float(E[0])

    V = mesh.V + 0.05 * rng.standard_normal(mesh.V.shape)
    np.testing.assert_allclose(step(V), _energy_ref(arap, V, arap.rotations(V)), rtol=1e-5)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()
        step(mesh.V + 0.05 * rng.standard_normal(mesh.V.shape))  # new points, new rotations
        jit = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert jit and all(k["cache_hit"] for k in jit)


@pytest.mark.parametrize("V, F, kwargs, match", [
    (np.zeros((4, 2)), [[0, 1, 2]], {}, r"ARAP\(\): expected rest vertices of shape \(k, 3\) with k > 0, got shape "
                                        r"\(4, 2\)"),
    (np.zeros((0, 3)), [[0, 1, 2]], {}, r"ARAP\(\): expected rest vertices of shape \(k, 3\) with k > 0, got shape "
                                        r"\(0, 3\)"),
    ([[0, 0, 0], [1, 0, 0], [np.nan, 1, 0]], [[0, 1, 2]], {},
     r"ARAP\(\): expected finite rest vertices, got row 2 = \[nan, 1.0, 0.0\]"),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 3]], {}, r"ARAP\(\): expected face indices in \[0, 3\), got face 0 = "
                                                         r"\[0, 1, 3\]"),
    ([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]], {}, r"ARAP\(\): expected rest faces of non-zero area \(cotangent "
                                                         r"weights\), got face 0 = \[0, 1, 2\] of zero area"),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], {"min_weight": 0.0}, r"ARAP\(\): expected a finite min_weight > "
                                                                          r"0, got 0.0"),
])
def test_constructor_errors(V, F, kwargs, match):
    with pytest.raises(ValueError, match=match):
        ARAP(np.asarray(V, dtype=float), np.asarray(F), **kwargs)


def test_energy_and_rotation_errors():
    mesh = icosahedron()
    arap = ARAP(mesh.V, mesh.F)
    n = len(mesh.V)
    with pytest.raises(ValueError, match=rf"ARAP.energy\(\): expected {3 * n} control coordinates \({n} points, xyz "
                                         rf"interleaved\), got {3 * n - 3}"):
        arap.energy(mi.Float(np.zeros(3 * n - 3, np.float32)))
    with pytest.raises(ValueError, match=rf"ARAP.energy\(\): expected {n} control points, got {n + 1}"):
        arap.energy(mi.Point3f(np.zeros((3, n + 1), np.float32)))
    with pytest.raises(TypeError, match=r"ARAP.energy\(\): expected control points as mi.Float \(3n\).*got list"):
        arap.energy(mesh.V.tolist())
    with pytest.raises(ValueError, match=rf"ARAP.energy\(\): expected R of shape \({n}, 3, 3\), got \(3, 3\)"):
        arap.energy(flat(mesh.V, grad=True), np.eye(3))
    with pytest.raises(ValueError, match=r"ARAP.energy\(\): expected finite rotations R .*got non-finite entries"):
        arap.energy(flat(mesh.V, grad=True), np.full((n, 3, 3), np.nan))
    V = mesh.V.copy()
    V[4, 1] = np.inf
    with pytest.raises(ValueError, match=r"ARAP.rotations\(\): expected finite control points, got point 4 = \[.*inf"):
        arap.rotations(V)
    with pytest.raises(ValueError, match=r"ARAP.rotations\(\): expected \(12, 3\) control points, got shape \(5, 3\)"):
        arap.rotations(mesh.V[:5])


def test_covariances_by_hand_and_rotations_match_the_svd():
    """S_i from the sparse product K V against the sum over the directed edges, vertex by vertex."""
    from mi_loop.datasets import icosphere
    from mi_loop.energies.rotations import svd_rotations

    V, F = icosphere(2)
    V2 = V + 0.05 * np.random.default_rng(0).normal(size=V.shape)
    arap = ARAP(V, F)
    S = arap.covariances(V2)
    e_cur = V2[arap.I] - V2[arap.J]
    by_hand = np.zeros_like(S)
    np.add.at(by_hand, arap.I, arap.w[:, None, None] * arap.e_rest[:, :, None] * e_cur[:, None, :])
    # the same float64 sums in another order: |S| <= 0.19
    np.testing.assert_allclose(S, by_hand, rtol=1e-12, atol=1e-15)
    # 1e-10 is the bound of tests/energies/test_rotations.py, whose worst case
    # (random covariances with reflections) measured 2.3e-13, the error growing as eps / eigen-gap
    np.testing.assert_allclose(arap.rotations(V2), svd_rotations(S), atol=1e-10)
