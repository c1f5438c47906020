"""The coverage term: values and gradients against NumPy, its effect on a fit, its errors."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from scipy.spatial import cKDTree

from mi_loop.ad.operator import LimitOperator
from mi_loop.datasets import icosphere
from mi_loop.energies.coverage import Coverage
from mi_loop.energies.imls import IMLS
from mi_loop.fitting.static import sample_parameters
from mi_loop.mesh.sampling import sample_surface

from helpers import as_numpy, point3f


def brute_nearest(P, Q):
    """Nearest sample of every point by a full distance matrix (no k-d tree)."""
    return np.argmin(((P[:, None, :] - Q[None, :, :]) ** 2).sum(-1), axis=1)


@pytest.fixture
def cloud():
    rng = np.random.default_rng(3)
    P = rng.normal(size=(300, 3))
    N = rng.normal(size=(300, 3))
    Q = rng.normal(size=(80, 3))
    return P, N, Q


def test_energy_and_gradient_match_numpy(cloud):
    P, N, Q = cloud
    cover = Coverage(P, N, isolation=1e9)               # keep every point of the Gaussian cloud
    cover.update(Q)
    j = brute_nearest(P, Q)
    np.testing.assert_array_equal(cover.nearest, j)
    n = N / np.linalg.norm(N, axis=1, keepdims=True)
    r = np.einsum("ij,ij->i", n, Q[j] - P)
    q = point3f(Q)
    dr.enable_grad(q)
    E = cover.energy(q)
    dr.backward(E)
    np.testing.assert_allclose(float(E[0]), np.mean(r ** 2), rtol=1e-5)
    expected = np.zeros_like(Q)
    np.add.at(expected, j, 2.0 / len(P) * r[:, None] * n)
    grad = as_numpy(dr.grad(q))
    np.testing.assert_allclose(grad, expected, rtol=0, atol=1e-5 * np.abs(expected).max())
    assert (np.abs(expected[np.setdiff1d(np.arange(len(Q)), j)]) == 0).all()   # unused samples get none


def test_gradient_through_the_limit_operator_with_imls_is_the_sum_of_both():
    """IMLS and coverage both gather from the same limit samples; Dr.Jit must add both gradients."""
    V, F = icosphere(2)
    rng = np.random.default_rng(0)
    x0 = (0.9 * V + rng.normal(scale=0.02, size=V.shape)).ravel().astype(np.float32)
    Vt, Ft = icosphere(3)
    P, N, _ = sample_surface(Vt, Ft, 3000, seed=1)
    op = LimitOperator(F, len(V), *sample_parameters(F, len(V), "level1"), derivatives=False)
    Q0 = as_numpy(op.positions(mi.Float(x0)))
    imls, cover = IMLS(P, N), Coverage(P, N)
    imls.update(Q0)
    cover.update(Q0)

    def grad(terms):
        x = mi.Float(x0)
        dr.enable_grad(x)
        Q = op.positions(x)
        E = sum((t(Q) for t in terms), mi.Float(0.0))
        dr.backward(E)
        return as_numpy(dr.grad(x))

    g_imls = grad([lambda Q: imls.energy(Q, reduce="mean")])
    g_cover = grad([cover.energy])
    g_both = grad([lambda Q: imls.energy(Q, reduce="mean"), cover.energy])
    assert np.abs(g_cover[:, 2]).max() > 1e-4 * np.abs(g_cover).max()
    np.testing.assert_allclose(g_both, g_imls + g_cover, rtol=0, atol=1e-5 * np.abs(g_both).max())


def test_a_shared_tree_gives_the_same_weights(cloud):
    P, N, _ = cloud
    own, shared = Coverage(P, N), Coverage(P, N, tree=IMLS(P, N).tree)
    np.testing.assert_array_equal(shared.weight, own.weight)


def test_coverage_pulls_the_fit_out_to_a_spike():
    """A unit sphere with a narrow bump 0.5 high: IMLS alone stops short of its tip; coverage reaches it."""
    from mi_loop.fitting.sequence import SequenceOptions, fit_frame
    from mi_loop.mesh.sampling import closest_points
    from mi_loop.subdiv.masks import limit_mesh

    Vt, Ft = icosphere(4)
    polar = np.arccos(np.clip(Vt[:, 1], -1, 1))
    Vt = Vt * (1 + 0.5 * np.exp(-(polar / 0.15) ** 2))[:, None]
    tip = Vt[np.argmax(Vt[:, 1])]
    P, N, _ = sample_surface(Vt, Ft, 20_000, seed=0)
    V0, F = icosphere(2)
    op = LimitOperator(F, len(V0), *sample_parameters(F, len(V0), "level1"), derivatives=False)
    miss = {}
    for weight in (0.0, 1.0):
        options = SequenceOptions(cover=weight, image=False, iterations=150, stiff_factor=1.0)
        V, _ = fit_frame(V0, F, P, N, op, None, options, frame=0, lr=0.02)
        VL, FL = limit_mesh(V, F, level=3)[:2]
        miss[weight] = closest_points(VL, FL, tip[None])[0][0]
    assert miss[1.0] < 0.5 * miss[0.0], miss


def test_isolated_points_are_left_out():
    """A grid of data points plus three stray points far above it: the strays get weight 0
    and do not pull the samples; a lone point slightly off the grid still counts."""
    g = np.linspace(0, 1, 30)
    P = np.array([(x, y, 0.0) for x in g for y in g])
    P[0, 2] = 0.02
    strays = np.array([[0.5, 0.5, 2.0], [0.1, 0.9, -3.0], [0.8, 0.2, 5.0]])
    P = np.vstack([P, strays])
    N = np.tile([0.0, 0.0, 1.0], (len(P), 1))
    cover = Coverage(P, N)
    np.testing.assert_array_equal(cover.weight, np.r_[np.ones(900), np.zeros(3)])
    Q = P[:900:7].copy()
    Q[:, 2] = 0.0
    cover.update(Q)
    kept = P[:900]
    expected = np.mean((Q[brute_nearest(kept, Q), 2] - kept[:, 2]) ** 2)
    np.testing.assert_allclose(float(cover.energy(point3f(Q))[0]), expected, rtol=1e-5)


@pytest.mark.parametrize("call, message", [
    (lambda P, N: Coverage(P[:, :2], N), r"Coverage\(\): expected points of shape \(k, 3\) with k > 0, got shape "
                                         r"\(300, 2\)"),
    (lambda P, N: Coverage(P, N[:-1]), r"Coverage\(\): expected normals of the points' shape \(300, 3\), got shape "
                                       r"\(299, 3\)"),
    (lambda P, N: Coverage(np.where(np.arange(300)[:, None] == 7, np.nan, P), N),
     r"Coverage\(\): expected finite points, got row 7 = \[nan, nan, nan\]"),
    (lambda P, N: Coverage(P, np.where(np.arange(300)[:, None] == 4, 0.0, N)),
     r"Coverage\(\): expected non-zero normals, got normal 4 = \[0.0, 0.0, 0.0\]"),
    (lambda P, N: Coverage(P, N, isolation=1.0), r"Coverage: isolation must be a number > 1, got 1.0"),
    (lambda P, N: Coverage(P, N, tree=cKDTree(P[:-1])),
     r"Coverage: tree must be a k-d tree of these points \(e.g. IMLS\(points, ...\).tree\)"),
    (lambda P, N: Coverage(P, N, tree=cKDTree(P + 1.0)), r"Coverage: tree must be a k-d tree of these points"),
])
def test_bad_inputs_are_named(cloud, call, message):
    P, N, _ = cloud
    with pytest.raises(ValueError, match=message):
        call(P, N)


def test_energy_needs_a_matching_update(cloud):
    P, N, Q = cloud
    cover = Coverage(P, N)
    with pytest.raises(ValueError, match=r"Coverage.energy: call update\(Q\) first"):
        cover.energy(point3f(Q))
    cover.update(Q)
    with pytest.raises(ValueError, match=r"Coverage.energy: expected 80 samples \(as at the last update\), got 79"):
        cover.energy(point3f(Q[:-1]))
    with pytest.raises(ValueError, match=r"Coverage.update\(\): expected samples of shape \(k, 3\) with k > 0, got "
                                         r"shape \(80, 2\)"):
        cover.update(Q[:, :2])
    Q[5, 0] = np.inf
    with pytest.raises(ValueError, match=r"Coverage.update\(\): expected finite samples, got row 5 = \[inf"):
        cover.update(Q)
