"""The one-pass composition of limit rows (``mi_loop.subdiv.compose``) against the sparse product it replaces.

Oracle: the level rows of :func:`~mi_loop.subdiv.limit.level_rows` (padded,
over the level-``L`` vertices) times the composed subdivision matrix ``S_L``,
as a SciPy sparse product; ``level_rows`` itself is checked against iterated
subdivision in ``test_limit_exact.py``. Every test mesh (creases, semi-sharp
edges, darts, boundaries, irregular vertices next to each other), samples
inside faces, on their edges and at their corners.
"""
from __future__ import annotations

import numba
import numpy as np
import pytest

import mi_loop
from mi_loop.subdiv.compose import composed_rows
from mi_loop.subdiv.hierarchy import build_hierarchy
from mi_loop.subdiv.limit import check_samples, level_rows, padded_to_csr

import meshes

DERIVATIVES = (None, "u", "v")


def samples(F, k: int, seed: int):
    """``k`` random samples, a fifth of them on a face's edge midpoint, corner or centre."""
    rng = np.random.default_rng(seed)
    fid = rng.integers(0, len(F), k)
    uv = rng.dirichlet(np.ones(3), k)[:, 1:].copy()
    special = np.array([[0, 0], [1, 0], [0, 1], [0.5, 0], [0, 0.5], [0.5, 0.5], [1 / 3, 1 / 3], [0.25, 0]])
    uv[: k // 5] = special[rng.integers(0, len(special), k // 5)]
    return fid, uv


@pytest.mark.parametrize("name", list(meshes.MESHES))
def test_composed_rows_equal_the_sparse_product(name):
    mesh = meshes.MESHES[name]
    h = build_hierarchy(mesh.F, len(mesh.V), creases=mesh.creases)
    fid, uv = check_samples(*samples(mesh.F, 300, 7), len(mesh.F), "test", h.levels[0].hole)
    got = composed_rows(h, fid, uv, DERIVATIVES)
    for (idx, W), M, d in zip(level_rows(h, fid, uv, DERIVATIVES), got, DERIVATIVES):
        want = (padded_to_csr(idx, W, h.top.n) @ h.composed()).tocsr()
        scale = abs(want).max()
        assert M.shape == want.shape == (len(fid), len(mesh.V))
        assert abs(M - want).max() <= 1e-14 * scale, (d, abs(M - want).max())
        assert M.has_sorted_indices
        rows = np.repeat(np.arange(M.shape[0]), np.diff(M.indptr))
        assert np.all((np.diff(M.indices) > 0) | (np.diff(rows) > 0)), "columns not strictly increasing in a row"
        assert np.all(M.data != 0), "explicit zeros"


def test_tuple_call_equals_separate_calls_bit_for_bit():
    mesh = meshes.MESHES["mixed_sharpness"]
    fid, uv = samples(mesh.F, 500, 3)
    together = mi_loop.limit_matrix(mesh.F, len(mesh.V), fid, uv, mesh.creases, derivative=DERIVATIVES)
    assert isinstance(together, tuple) and len(together) == 3
    for M, d in zip(together, DERIVATIVES):
        alone = mi_loop.limit_matrix(mesh.F, len(mesh.V), fid, uv, mesh.creases, derivative=d)
        assert (M != alone).nnz == 0 and np.array_equal(M.indices, alone.indices)
    op = mi_loop.LimitOperator(mesh.F, len(mesh.V), fid, uv, mesh.creases)
    for M, N in zip(together, op.matrix(list(DERIVATIVES))):
        assert (M != N).nnz == 0


def test_repeated_derivatives_are_separate_matrices():
    mesh = meshes.MESHES["icosahedron"]
    fid, uv = samples(mesh.F, 50, 4)
    a, b = mi_loop.limit_matrix(mesh.F, len(mesh.V), fid, uv, derivative=("u", "u"))
    assert a is not b and (a != b).nnz == 0
    b.data[:] = 0.0                                  # editing one leaves the other
    assert abs(a).max() > 0


def test_rows_follow_the_samples_and_ignore_the_thread_count():
    """Shuffling samples shuffles rows exactly; one thread or all give the same bits."""
    mesh = meshes.MESHES["grid_semisharp2"]
    fid, uv = samples(mesh.F, 2000, 5)
    order = np.random.default_rng(1).permutation(len(fid))
    base = mi_loop.limit_matrix(mesh.F, len(mesh.V), fid, uv, mesh.creases, derivative=DERIVATIVES)
    shuffled = mi_loop.limit_matrix(mesh.F, len(mesh.V), fid[order], uv[order], mesh.creases, derivative=DERIVATIVES)
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        single = mi_loop.limit_matrix(mesh.F, len(mesh.V), fid, uv, mesh.creases, derivative=DERIVATIVES)
    finally:
        numba.set_num_threads(threads)
    for B, S, T in zip(base, shuffled, single):
        assert (B[order] != S).nnz == 0
        assert np.array_equal(B.data, T.data) and np.array_equal(B.indices, T.indices)
