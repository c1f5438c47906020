"""Closed-form best rotations (mi_loop.energies.rotations) against the SVD, on the cases that break closed forms."""
from __future__ import annotations

import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mi_loop.energies.rotations import RotationSolver, best_rotations, svd_rotations


@pytest.fixture(scope="module", params=["numpy", "kernel"])
def solve(request):
    """Both implementations: the NumPy function and the compiled Dr.Jit kernel (one solver, replayed)."""
    return best_rotations if request.param == "numpy" else RotationSolver()


def covariances(A, R):
    """``S = sum_j a_j (R a_j)^T`` for point sets ``A`` (n, k, 3) and rotations ``R`` (n, 3, 3)."""
    return np.einsum("nka,nkb->nab", A, np.einsum("nab,nkb->nka", R, A))


def check_rotations(R):
    np.testing.assert_allclose(np.swapaxes(R, 1, 2) @ R, np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)


def test_random_covariances_match_the_svd_with_its_reflection_fix(solve):
    S = np.random.default_rng(0).normal(size=(5000, 3, 3))
    assert (np.linalg.det(S) < 0).mean() > 0.4                    # half of them would give reflections
    R = solve(S)
    check_rotations(R)
    np.testing.assert_allclose(R, svd_rotations(S), atol=1e-10)


def test_exact_rotations_are_recovered_also_near_half_turns(solve):
    rng = np.random.default_rng(1)
    axis = rng.normal(size=(2000, 3))
    angle = np.r_[rng.uniform(0, np.pi, 1000), np.pi - 10.0 ** rng.uniform(-12, -2, 1000)]   # up to 180 deg
    Rt = Rotation.from_rotvec(axis / np.linalg.norm(axis, axis=1, keepdims=True) * angle[:, None]).as_matrix()
    R = solve(covariances(rng.normal(size=(2000, 6, 3)), Rt))
    np.testing.assert_allclose(R, Rt, atol=1e-12)


def test_planar_one_rings_with_equal_singular_values(solve):
    """A regular flat vertex: S = c P R^T, singular values (c, c, 0); the rotation is still unique."""
    ring = np.c_[np.cos(np.arange(6) * np.pi / 3), np.sin(np.arange(6) * np.pi / 3), np.zeros(6)]
    Rt = Rotation.random(500, random_state=2).as_matrix()
    S = covariances(np.broadcast_to(ring, (500, 6, 3)), Rt)
    assert np.allclose(np.linalg.svd(S, compute_uv=False), [[3, 3, 0]], atol=1e-12)
    np.testing.assert_allclose(solve(S), Rt, atol=1e-12)


def test_degenerate_covariances_still_get_an_optimal_rotation(solve):
    """Rank 1 (collinear edges): many optimal rotations; the one returned attains the optimum tr(R S)."""
    rng = np.random.default_rng(3)
    S = np.einsum("na,nb->nab", rng.normal(size=(300, 3)), rng.normal(size=(300, 3)))
    R = solve(S)
    check_rotations(R)
    best = np.einsum("nab,nba->n", svd_rotations(S), S)
    np.testing.assert_allclose(np.einsum("nab,nba->n", R, S), best, rtol=1e-10)


def test_zero_gives_the_identity_and_scale_does_not_matter(solve):
    S = np.random.default_rng(4).normal(size=(100, 3, 3))
    np.testing.assert_array_equal(solve(np.zeros((2, 3, 3))), np.broadcast_to(np.eye(3), (2, 3, 3)))
    np.testing.assert_allclose(solve(1e-30 * S), solve(1e30 * S), atol=1e-12)


@pytest.mark.parametrize("shape", [(3, 3), (4, 3, 2), (2, 9)])
def test_best_rotations_rejects_other_shapes(shape):
    with pytest.raises(ValueError, match=re.escape(f"best_rotations(): expected S of shape (n, 3, 3), got {shape}")):
        best_rotations(np.zeros(shape))


def test_the_kernel_matches_numpy_and_replays_for_other_sizes():
    """One recording, replayed at other n (and again at the first): the same rotations as the NumPy passes."""
    solve = RotationSolver()
    rng = np.random.default_rng(5)
    for n in (700, 33, 700, 1):
        S = rng.normal(size=(n, 3, 3))
        R = solve(S)
        assert R.shape == (n, 3, 3)
        np.testing.assert_allclose(R, best_rotations(S), atol=1e-11)
    S = rng.normal(size=(50, 3, 3))
    np.testing.assert_array_equal(solve(S), solve(S.copy()))                 # deterministic


@pytest.mark.parametrize("shape", [(3, 3), (4, 3, 2)])
def test_rotation_solver_rejects_other_shapes(shape):
    with pytest.raises(ValueError, match=re.escape(f"RotationSolver(): expected S of shape (n, 3, 3), got {shape}")):
        RotationSolver()(np.zeros(shape))


@pytest.mark.parametrize("tol", [0.0, -1.0, float("nan"), "1e-9"])
def test_rotation_solver_rejects_bad_tolerances(tol):
    with pytest.raises(ValueError, match=re.escape(f"RotationSolver(): expected a finite tol > 0, got {tol!r}")):
        RotationSolver(tol=tol)
