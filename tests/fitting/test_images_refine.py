"""One exact Loop step of the control mesh leaves the limit surface (and the colour field) unchanged."""
from __future__ import annotations

import numpy as np
import pytest

from mi_loop import datasets
from mi_loop.fitting.images import refine
from mi_loop.subdiv.limit import limit_matrix

#: Child k of face (a, b, c) has corners (a, ab, ca), (ab, b, bc), (ca, bc, c), (bc, ca, ab)
#: (mi_loop.subdivision_matrix); their parent barycentrics (w_a, w_b, w_c):
CHILD_CORNERS = np.array([
    [[1, 0, 0], [0.5, 0.5, 0], [0.5, 0, 0.5]],
    [[0.5, 0.5, 0], [0, 1, 0], [0, 0.5, 0.5]],
    [[0.5, 0, 0.5], [0, 0.5, 0.5], [0, 0, 1]],
    [[0, 0.5, 0.5], [0.5, 0, 0.5], [0.5, 0.5, 0]],
])


def meshes():
    V, F = datasets.icosphere(1)
    rng = np.random.default_rng(0)
    yield pytest.param(V * rng.uniform(0.7, 1.3, size=(len(V), 1)), F, id="bumpy-icosphere")   # valence 5, 6
    yield pytest.param(*datasets.blob(), id="blob")


@pytest.mark.parametrize("V, F", list(meshes()))
def test_the_refined_limit_surface_is_the_same_surface(V, F):
    V_fine, F_fine, A_fine = refine(V, F, albedo=np.random.default_rng(1).uniform(size=V.shape))
    assert len(F_fine) == 4 * len(F) and len(V_fine) == len(V) + len(F) * 3 // 2
    rng = np.random.default_rng(2)
    k = 400
    child = rng.integers(0, len(F_fine), k)
    uv = rng.dirichlet([1, 1, 1], k)[:, 1:]            # (u, v) inside the child triangle
    w = np.c_[1 - uv.sum(1), uv]                        # barycentrics of the corners (0, 1, 2)
    parent_bary = np.einsum("kc,kcj->kj", w, CHILD_CORNERS[child % 4])
    parent, parent_uv = child // 4, parent_bary[:, 1:]
    W_coarse = limit_matrix(F, len(V), parent, parent_uv)
    W_fine = limit_matrix(F_fine, len(V_fine), child, uv)
    diag = np.linalg.norm(V.max(0) - V.min(0))
    assert np.abs(W_fine @ V_fine - W_coarse @ V).max() < 1e-12 * diag
    A = np.asarray(A_fine)
    assert np.abs(W_fine @ A - W_coarse @ np.random.default_rng(1).uniform(size=V.shape)).max() < 1e-12


def irregular_sphere():
    """The convex hull of 300 random unit vectors, faces outward: valences 3 to 9, whose Loop weights sum to
    1 + 4e-16 at about a third of the new vertices."""
    from scipy.spatial import ConvexHull

    V = np.random.default_rng(0).normal(size=(300, 3))
    V /= np.linalg.norm(V, axis=1, keepdims=True)
    F = ConvexHull(V).simplices
    inward = np.einsum("ij,ij->i", np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), V[F].mean(1)) < 0
    F[inward] = F[inward][:, ::-1]
    return V, F


@pytest.mark.parametrize("V, F", [*meshes(), pytest.param(*irregular_sphere(), id="irregular-sphere")])
def test_a_refined_albedo_stays_in_the_range_of_the_coarse_one(V, F):
    """An albedo saturated at exactly 0 or 1 stays there (sums of weights that round to 1 + 4e-16 are clipped),
    so a fit whose albedo reached 1 before a refinement is not refused after it."""
    A = np.ones(V.shape)
    A[::3] = 0.0
    A[1::3, 1] = 0.25
    _, _, A_fine = refine(V, F, albedo=A)
    assert A_fine.min() >= 0.0 and A_fine.max() <= 1.0
    assert (A_fine.max(axis=0) <= A.max(axis=0)).all() and (A_fine.min(axis=0) >= A.min(axis=0)).all()
    ones = refine(V, F, albedo=np.ones(V.shape))[2]
    np.testing.assert_array_equal(ones, 1.0)
