"""One Loop step: ``mi_loop.subdivision_matrix`` against the plain oracle.

The oracle (``tests/oracle_loop.py``) numbers new vertices by its own edge
order; the code under test may use any order, so fine vertices are matched
through the child-face convention: for the control face (a, b, c) the rows
4f..4f+3 of ``F_fine`` are (a, ab, ca), (ab, b, bc), (ca, bc, c), (bc, ca, ab).
"""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

import mi_loop

import meshes
import oracle_loop as oracle

MESH_NAMES = list(meshes.MESHES)


def edge_vertices_from_children(F, F_fine, n_vertices):
    """Return {sorted edge: fine index} read off F_fine; check the child convention."""
    F_fine = np.asarray(F_fine)
    edge_vertex = {}
    for f, (a, b, c) in enumerate(np.asarray(F)):
        ab, ca = F_fine[4 * f, 1], F_fine[4 * f, 2]
        bc = F_fine[4 * f + 1, 2]
        expected = np.array([[a, ab, ca], [ab, b, bc], [ca, bc, c], [bc, ca, ab]])
        np.testing.assert_array_equal(F_fine[4 * f:4 * f + 4], expected,
                                      err_msg=f"children of face {f} = {(a, b, c)}")
        for e, m in ((oracle.edge_key(a, b), ab), (oracle.edge_key(b, c), bc), (oracle.edge_key(c, a), ca)):
            if edge_vertex.setdefault(e, m) != m:
                raise AssertionError(f"edge {e} has two fine vertices {edge_vertex[e]} and {m}")
    return edge_vertex


@pytest.mark.parametrize("name", MESH_NAMES)
def test_one_step_matches_oracle(name):
    mesh = meshes.MESHES[name]
    n = len(mesh.V)
    S, F_fine = mi_loop.subdivision_matrix(mesh.F, n, creases=mesh.creases)
    S_ref, F_fine_ref, edge_vertex_ref = oracle.one_step_matrix(mesh.F, n, mesh.creases)

    assert sp.issparse(S) and S.format == "csr" and S.dtype == np.float64
    assert S.shape == S_ref.shape
    assert np.shape(F_fine) == (4 * len(mesh.F), 3)

    # Child convention and one fine vertex per undirected edge, numbered n.. n_fine-1.
    edge_vertex = edge_vertices_from_children(mesh.F, F_fine, n)
    assert set(edge_vertex) == set(edge_vertex_ref)
    assert sorted(edge_vertex.values()) == list(range(n, S.shape[0]))

    # Permutation code index -> oracle index; the old vertices keep their indices.
    to_ref = np.arange(S.shape[0])
    for e, m in edge_vertex.items():
        to_ref[m] = edge_vertex_ref[e]
    S_dense, S_ref_dense = S.toarray(), S_ref.toarray()[to_ref]
    np.testing.assert_allclose(S_dense[:n], S_ref_dense[:n], rtol=0, atol=1e-14,
                               err_msg=f"{name}: vertex points")
    np.testing.assert_allclose(S_dense[n:], S_ref_dense[n:], rtol=0, atol=1e-14,
                               err_msg=f"{name}: edge points")
    np.testing.assert_array_equal(to_ref[np.asarray(F_fine)], np.asarray(F_fine_ref))
    np.testing.assert_allclose(S @ mesh.V, S_ref_dense @ mesh.V, rtol=0, atol=1e-13)


@pytest.mark.parametrize("name", MESH_NAMES)
def test_rows_sum_to_one(name):
    mesh = meshes.MESHES[name]
    S, _ = mi_loop.subdivision_matrix(mesh.F, len(mesh.V), creases=mesh.creases)
    np.testing.assert_allclose(np.asarray(S.sum(axis=1)).ravel(), 1.0, rtol=0, atol=1e-14)
    assert S.min() >= 0.0  # Loop's weights are non-negative for every valence


def test_tetrahedron_step_by_hand():
    """Valence 3: beta = (5/8 - (3/8 - 1/8)^2)/3 = 3/16, centre 1 - 3 beta = 7/16."""
    F = np.array([[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]])
    S, F_fine = mi_loop.subdivision_matrix(F, 4)
    np.testing.assert_allclose(S.toarray()[:4], np.full((4, 4), 3 / 16) + np.eye(4) / 4, rtol=0, atol=1e-15)
    edge_vertex = edge_vertices_from_children(F, F_fine, 4)
    for (a, b), m in edge_vertex.items():
        c, d = sorted(set(range(4)) - {a, b})
        expected = np.zeros(4)
        expected[[a, b]] = 3 / 8
        expected[[c, d]] = 1 / 8
        np.testing.assert_allclose(S.toarray()[m], expected, rtol=0, atol=1e-15, err_msg=f"edge {a}-{b}")


def test_boundary_and_crease_rules_by_hand():
    """Open fan of two triangles (0, 1, 2), (0, 2, 3): 1 and 3 have one face (corners)."""
    F = np.array([[0, 1, 2], [0, 2, 3]])
    S, F_fine = mi_loop.subdivision_matrix(F, 4)
    D = S.toarray()
    edge_vertex = edge_vertices_from_children(F, F_fine, 4)
    # 0 and 2 have two boundary edges each (to 1 and 3): crease rule 1/8, 3/4, 1/8.
    np.testing.assert_allclose(D[:4], [[3 / 4, 1 / 8, 0, 1 / 8], [0, 1, 0, 0],
                                       [0, 1 / 8, 3 / 4, 1 / 8], [0, 0, 0, 1]], rtol=0, atol=1e-15)
    np.testing.assert_allclose(D[edge_vertex[(0, 2)]], [3 / 8, 1 / 8, 3 / 8, 1 / 8], rtol=0, atol=1e-15)
    np.testing.assert_allclose(D[edge_vertex[(0, 1)]], [1 / 2, 1 / 2, 0, 0], rtol=0, atol=1e-15)

    # Edge 0-2 infinitely sharp: midpoint; 0 and 2 now have three sharp edges -> corners.
    S, F_fine = mi_loop.subdivision_matrix(F, 4, creases=np.array([[2, 0]]))
    D = S.toarray()
    edge_vertex = edge_vertices_from_children(F, F_fine, 4)
    np.testing.assert_allclose(D[edge_vertex[(0, 2)]], [1 / 2, 0, 1 / 2, 0], rtol=0, atol=1e-15)
    np.testing.assert_allclose(D[:4], np.eye(4), rtol=0, atol=1e-15)


def test_semi_sharp_sharpness_one_is_sharp_once():
    """Sharpness 1 acts in the first step only: midpoint at step 1, smooth rule at step 2."""
    mesh = meshes.icosahedron_crease_loop(1)
    n = len(mesh.V)
    S, F_fine = mi_loop.subdivision_matrix(mesh.F, n, creases=mesh.creases)
    edge_vertex = edge_vertices_from_children(mesh.F, F_fine, n)
    E, _ = mesh.creases
    for a, b in E:
        m = edge_vertex[oracle.edge_key(a, b)]
        expected = np.zeros(n)
        expected[[a, b]] = 0.5
        np.testing.assert_allclose(S.toarray()[m], expected, rtol=0, atol=1e-15)
    # Second step on the fine mesh with no creases left: plain smooth Loop.
    S2, _ = mi_loop.subdivision_matrix(np.asarray(F_fine), S.shape[0])
    S2_ref, _, _ = oracle.one_step_matrix(np.asarray(F_fine), S.shape[0])
    n1 = S.shape[0]
    np.testing.assert_allclose(S2.toarray()[:n1], S2_ref.toarray()[:n1], rtol=0, atol=1e-15)
