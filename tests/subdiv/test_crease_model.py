"""OpenSubdiv's crease model in one subdivision step, checked against rows derived by hand from its rules.

Each expected row is written out from the Sdc rules (Loop scheme): smooth
edge ``3/8, 3/8, 1/8, 1/8``, crease edge ``1/2, 1/2``; smooth vertex
``1 - k beta, beta``, crease vertex ``3/4, 1/8, 1/8``, corner ``1``; a
semi-sharp edge whose children become smooth blends its crease and smooth
points with weight ``s``; a vertex whose rule changes blends the parent and
child rule masks with the mean sharpness of what decays to smooth (at most
1); Chaikin: a child edge at a vertex gets ``3/4 s + 1/4 mean(others) - 1``.
The limit surface under every rule is checked against the independent
oracle in ``test_crease_model_limit.py``.
"""
from __future__ import annotations

import re

import numpy as np
import pytest

import mi_loop

from meshes import grid_faces

# A 5 x 5 lattice: vertex i + 5 j; 12 = (2, 2) is interior, valence 6; 0 is a corner of one face.
F = grid_faces(5, 5)
N = 25
CENTRE = 12
RING = (7, 8, 11, 13, 16, 17)        # neighbours of 12 in grid_faces' diagonal pattern


def row(S, i):
    """Row ``i`` of a sparse matrix as a dense float array."""
    return S[i].toarray().ravel()


def unit(*pairs):
    """Dense row with ``{vertex: weight}`` entries."""
    out = np.zeros(N)
    for v, w in pairs:
        out[v] += w
    return out


def edge_point_index(E_all, a, b):
    """Fine vertex of edge ``a - b`` in :func:`mi_loop.subdivision_matrix` (``n`` + edge id, edges sorted)."""
    return N + int(np.flatnonzero((E_all[:, 0] == min(a, b)) & (E_all[:, 1] == max(a, b)))[0])


def edges_and_opposites():
    from mi_loop.mesh.halfedge import Topology

    return Topology.build(F, N).E


def test_ring_is_the_one_ring_of_the_centre():
    """The test's own premise: vertex 12's neighbours."""
    nb = {int(v) for f in F if CENTRE in f for v in f} - {CENTRE}
    assert nb == set(RING)


def smooth_vertex(v, ring):
    k = len(ring)
    beta = (5 / 8 - (3 / 8 + np.cos(2 * np.pi / k) / 4) ** 2) / k
    return unit((v, 1 - k * beta), *((r, beta) for r in ring))


@pytest.mark.parametrize("s", [0.25, 0.5, 0.8, 1.0])
def test_semi_sharp_edge_below_one_blends_crease_and_smooth_edge_points(s):
    """Edge 12-13 of sharpness s <= 1: s (midpoint) + (1 - s) (3/8, 3/8, 1/8, 1/8)."""
    S, _ = mi_loop.subdivision_matrix(F, N, (np.array([[12, 13]]), [s]))
    opposite = [int(v) for f in F if 12 in f and 13 in f for v in f if v not in (12, 13)]
    expected = (s * unit((12, 0.5), (13, 0.5))
                + (1 - s) * unit((12, 3 / 8), (13, 3 / 8), *((o, 1 / 8) for o in opposite)))
    np.testing.assert_allclose(row(S, edge_point_index(edges_and_opposites(), 12, 13)), expected, atol=1e-15)


def test_semi_sharp_edge_above_one_is_a_crease_edge_point():
    S, _ = mi_loop.subdivision_matrix(F, N, (np.array([[12, 13]]), [1.5]))
    np.testing.assert_allclose(row(S, edge_point_index(edges_and_opposites(), 12, 13)),
                               unit((12, 0.5), (13, 0.5)), atol=1e-15)


@pytest.mark.parametrize("s, w", [(0.5, 0.5), (0.25, 0.25), (1.0, 1.0), (1.5, 1.0), (np.inf, 1.0)])
def test_vertex_sharpness_blends_corner_and_smooth_masks(s, w):
    """Vertex sharpness s at a smooth vertex: corner rule; decaying to 0 blends with weight min(s, 1)."""
    S, _ = mi_loop.subdivision_matrix(F, N, corners=([CENTRE], [s]))
    expected = w * unit((CENTRE, 1.0)) + (1 - w) * smooth_vertex(CENTRE, RING)
    np.testing.assert_allclose(row(S, CENTRE), expected, atol=1e-15)


def test_two_semi_sharp_edges_blend_crease_and_smooth_vertex_masks():
    """Crease 11-12-13 of sharpness 0.5 and 0.3: the mean 0.4 of (crease 3/4, 1/8, 1/8) and smooth."""
    S, _ = mi_loop.subdivision_matrix(F, N, (np.array([[11, 12], [12, 13]]), [0.5, 0.3]))
    crease = unit((CENTRE, 0.75), (11, 0.125), (13, 0.125))
    np.testing.assert_allclose(row(S, CENTRE), 0.4 * crease + 0.6 * smooth_vertex(CENTRE, RING), atol=1e-15)


def test_a_lasting_crease_keeps_the_crease_mask():
    """Sharpness 2 and 3: both children stay sharp, the plain crease rule."""
    S, _ = mi_loop.subdivision_matrix(F, N, (np.array([[11, 12], [12, 13]]), [2.0, 3.0]))
    np.testing.assert_allclose(row(S, CENTRE), unit((CENTRE, 0.75), (11, 0.125), (13, 0.125)), atol=1e-15)


def test_crease_with_a_decaying_third_edge_blends_corner_and_crease():
    """Two infinitely sharp edges and one of 0.5: corner rule now, crease rule next: 0.5 corner + 0.5 crease."""
    S, _ = mi_loop.subdivision_matrix(F, N, (np.array([[11, 12], [12, 13], [12, 17]]), [np.inf, np.inf, 0.5]))
    crease = unit((CENTRE, 0.75), (11, 0.125), (13, 0.125))
    np.testing.assert_allclose(row(S, CENTRE), 0.5 * unit((CENTRE, 1.0)) + 0.5 * crease, atol=1e-15)


def test_fine_sharpness_uniform_and_chaikin():
    """Crease 11-12-13 of sharpness 2 and 1: uniform children 1 | 1 and 0 | 0; Chaikin at vertex 12
    3/4 2 + 1/4 1 - 1 = 0.75 and 3/4 1 + 1/4 2 - 1 = 0.25, at the far ends (no other semi-sharp edge) 1 and 0."""
    from mi_loop.mesh.topology import sharp_topology
    from mi_loop.subdiv.subdivision import subdivide_topology

    E = edges_and_opposites()
    m11, m13 = edge_point_index(E, 11, 12), edge_point_index(E, 12, 13)
    for method, expected in (("uniform", {(11, m11): 1.0, (m11, 12): 1.0, (12, m13): 0.0, (m13, 13): 0.0}),
                             ("chaikin", {(11, m11): 1.0, (m11, 12): 0.75, (12, m13): 0.25, (m13, 13): 0.0})):
        topo = sharp_topology(F, N, "test", (np.array([[11, 12], [12, 13]]), [2.0, 1.0]), crease_method=method)
        _, fine = subdivide_topology(topo)
        for (a, b), s in expected.items():
            e = np.flatnonzero((fine.E[:, 0] == min(a, b)) & (fine.E[:, 1] == max(a, b)))
            assert len(e) == 1
            assert fine.sharpness[e[0]] == pytest.approx(s, abs=1e-15), (method, a, b)


def test_chaikin_ignores_infinitely_sharp_neighbours():
    """OpenSubdiv averages over semi-sharp edges only: next to an infinitely sharp edge, s - 1."""
    from mi_loop.mesh.topology import sharp_topology
    from mi_loop.subdiv.subdivision import child_edge_sharpness

    topo = sharp_topology(F, N, "test", (np.array([[11, 12], [12, 13]]), [2.5, np.inf]), crease_method="chaikin")
    e = np.flatnonzero((topo.E[:, 0] == 11) & (topo.E[:, 1] == 12))[0]
    np.testing.assert_allclose(child_edge_sharpness(topo)[e], [1.5, 1.5])


def test_chaikin_child_vertex_rule_decides_the_edge_point():
    """Chaikin: edge 12-13 of sharpness 0.9 next to 11-12 of 4 stays sharp at 12 (3/4 0.9 + 1/4 4 - 1 > 0)
    and decays at 13: the child point is a dart, so the edge point blends with weight s = 0.9."""
    S, _ = mi_loop.subdivision_matrix(F, N, (np.array([[11, 12], [12, 13]]), [4.0, 0.9]), crease_method="chaikin")
    opposite = [int(v) for f in F if 12 in f and 13 in f for v in f if v not in (12, 13)]
    expected = (0.9 * unit((12, 0.5), (13, 0.5))
                + 0.1 * unit((12, 3 / 8), (13, 3 / 8), *((o, 1 / 8) for o in opposite)))
    np.testing.assert_allclose(row(S, edge_point_index(edges_and_opposites(), 12, 13)), expected, atol=1e-15)
    S_u, _ = mi_loop.subdivision_matrix(F, N, (np.array([[11, 12], [12, 13]]), [4.0, 0.9]))
    np.testing.assert_allclose(row(S_u, edge_point_index(edges_and_opposites(), 12, 13)), expected, atol=1e-15)


def test_boundary_rules_at_a_corner_of_one_face():
    """Vertex 0 has one face: pinned under edge_and_corner, the crease rule under edge_only and none."""
    S, _ = mi_loop.subdivision_matrix(F, N)
    np.testing.assert_allclose(row(S, 0), unit((0, 1.0)), atol=1e-15)
    crease = unit((0, 0.75), (1, 0.125), (5, 0.125))
    for rule in ("edge_only", "none"):
        S, _ = mi_loop.subdivision_matrix(F, N, boundary=rule)
        np.testing.assert_allclose(row(S, 0), crease, atol=1e-15, err_msg=rule)
    S, _ = mi_loop.subdivision_matrix(F, N, boundary="edge_only", corners=[0])
    np.testing.assert_allclose(row(S, 0), unit((0, 1.0)), atol=1e-15)


def test_edge_only_corner_limit_is_the_boundary_curve():
    """Under edge_only the boundary is a cubic B-spline through the corner: limit 1/6, 2/3, 1/6 there."""
    V = np.c_[np.random.default_rng(0).standard_normal((N, 3))]
    P = mi_loop.limit_positions(V, F, boundary="edge_only")
    np.testing.assert_allclose(P[0], V[0] * 2 / 3 + (V[1] + V[5]) / 6, atol=1e-14)
    P = mi_loop.limit_positions(V, F)
    np.testing.assert_allclose(P[0], V[0], atol=1e-15)


def test_boundary_none_makes_holes_of_faces_at_soft_boundary_vertices():
    """Every face with a boundary vertex is a hole; sampling one is refused, the inner faces evaluate."""
    from mi_loop.mesh.topology import sharp_topology

    topo = sharp_topology(F, N, "test", boundary="none")
    on_boundary = np.zeros(N, bool)
    on_boundary[topo.E[topo.boundary].ravel()] = True
    np.testing.assert_array_equal(topo.hole, on_boundary[F].any(1))
    inner = int(np.flatnonzero(~topo.hole)[0])
    W = mi_loop.limit_matrix(F, N, np.array([inner]), np.array([[0.2, 0.3]]), boundary="none")
    np.testing.assert_allclose(W.toarray(), mi_loop.limit_matrix(F, N, np.array([inner]), np.array([[0.2, 0.3]]),
                                                                 boundary="edge_only").toarray(), atol=1e-15)
    message = ("limit_matrix(): expected samples on faces of the limit surface, got face 0 at sample 1, a hole "
               "under boundary='none' (a vertex of it is on a boundary that is not an infinitely sharp crease); "
               f"{int(topo.hole.sum())} of {len(F)} faces are holes")
    with pytest.raises(ValueError, match=re.escape(message)):
        mi_loop.limit_matrix(F, N, np.array([inner, 0]), np.array([[0.2, 0.3], [0.2, 0.3]]), boundary="none")
    with pytest.raises(ValueError, match=re.escape(message.replace("limit_matrix", "LimitOperator"))):
        mi_loop.LimitOperator(F, N, np.array([inner, 0]), np.array([[0.2, 0.3], [0.2, 0.3]]), boundary="none")


def test_boundary_none_keeps_faces_whose_boundary_edges_are_infinitely_sharp():
    """OpenSubdiv keeps the faces at a boundary vertex whose boundary edges are all given as infinitely sharp;
    a semi-sharp tag (5) does not keep them."""
    from mi_loop.mesh.topology import sharp_topology

    E = edges_and_opposites()
    plain = sharp_topology(F, N, "test", boundary="none")
    boundary_edges = E[plain.boundary]
    assert plain.hole.sum() > 0
    assert not sharp_topology(F, N, "test", boundary_edges, boundary="none").hole.any()
    semi = sharp_topology(F, N, "test", (boundary_edges, np.full(len(boundary_edges), 5.0)), boundary="none")
    np.testing.assert_array_equal(semi.hole, plain.hole)
    half = sharp_topology(F, N, "test", boundary_edges[boundary_edges.max(1) < 5], boundary="none")  # edge 0-4
    assert 0 < half.hole.sum() < plain.hole.sum()


def test_limit_mesh_leaves_the_holes_out():
    from mi_loop.mesh.topology import sharp_topology
    from mi_loop.subdiv.masks import limit_mesh

    V = np.c_[np.random.default_rng(1).standard_normal((N, 3))]
    holes = int(sharp_topology(F, N, "test", boundary="none").hole.sum())
    _, F_all, _ = limit_mesh(V, F, level=1, boundary="edge_only")
    _, F_kept, _ = limit_mesh(V, F, level=1, boundary="none")
    assert len(F_all) == 4 * len(F) and len(F_kept) == 4 * (len(F) - holes)
