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
