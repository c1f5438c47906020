"""The plain oracle (``tests/oracle_loop.py``) against OpenSubdiv 3.6 itself.

OpenSubdiv is reached through adobe-lagrange (``lagrange.subdivision.
subdivide_mesh``, Far uniform refinement and ``PrimvarRefinerReal<double>``).
Lagrange takes edge and vertex sharpness as attributes in [0, 1] that it
multiplies by 10 before handing them to OpenSubdiv (1 is
``SHARPNESS_INFINITE``), the boundary rule as ``vertex_boundary_interpolation``
and removes hole faces from its output; it has no crease-method option, so
OpenSubdiv runs with its default ``CREASE_UNIFORM``. The Chaikin rules are
checked here on hand-derived cases read off ``sdc/crease.cpp`` and
``sdc/scheme.h`` instead.

Refined points are compared at levels where every semi-sharp tag has expired
(and at the level itself, which is exact either way); refined vertices are
matched by position, and the matching must map lagrange's faces onto the
oracle's non-hole faces one to one. Limit points are compared with
OpenSubdiv's limit masks except at darts, where OpenSubdiv uses the smooth
mask and the oracle the exact eigenvector.
"""
from __future__ import annotations

import math

import lagrange
import numpy as np
import pytest

import meshes
import oracle_loop as oracle

TOL = 1e-12          # of the bounding-box size; both sides work in float64
INF = math.inf
ICO, TET, GRID = meshes.icosahedron(), meshes.tetrahedron(), meshes.grid(5, 4)
CUBE = meshes.creased_cube()
PATH = np.array([[0, 1], [1, 8], [8, 3], [3, 2], [2, 10], [10, 0]])     # closed loop on the icosahedron
STAR = np.array([[0, 1], [0, 5], [0, 10], [0, 11]])                      # edges at icosahedron vertex 0
GRID_BOUNDARY = np.array([[0, 1], [1, 2], [2, 3], [3, 4], [4, 9], [9, 14], [14, 19], [19, 18],
                          [18, 17], [17, 16], [16, 15], [15, 10], [10, 5], [5, 0]])
LAGRANGE_BOUNDARY = {"edge_and_corner": lagrange.subdivision.VertexBoundaryInterpolation.EdgeAndCorner,
                     "edge_only": lagrange.subdivision.VertexBoundaryInterpolation.EdgeOnly,
                     "none": lagrange.subdivision.VertexBoundaryInterpolation.NoInterpolation}


def _cases() -> dict:
    """Return {name: (TestMesh, oracle keywords)}: every rule lagrange can express."""
    cases = {f"ico_edge{s:g}": (ICO, dict(creases=(PATH[:1], [s]))) for s in (0.25, 0.5, 1.5, 2.25, 5.0, 10.0, 12.0)}
    cases["tet_edge1.5"] = (TET, dict(creases=(np.array([[0, 1]]), [1.5])))
    cases["ico_loop_mixed"] = (ICO, dict(creases=(PATH, [1.5, 0.5, 2.25, 3.0, 1.25, INF])))
    cases["ico_open_path"] = (ICO, dict(creases=(PATH[:3], [0.5, 2.25, 1.5])))      # crease ends at 0 and 3
    cases["ico_three_semi"] = (ICO, dict(creases=(STAR[:3], [1.75, 0.5, 2.5])))     # corner -> crease -> dart
    cases["ico_star"] = (ICO, dict(creases=(STAR, [0.5, 1.5, 2.5, INF])))
    cases["cube_semisharp"] = (CUBE, dict(creases=(CUBE.creases, np.resize([0.5, 1.5, 2.25], len(CUBE.creases)))))
    cases["ico_dart"] = (meshes.icosahedron_dart(), dict(creases=meshes.icosahedron_dart().creases))
    cases["grid_dart"] = (meshes.grid_dart(), dict(creases=meshes.grid_dart().creases))
    for vs in (0.5, 2.0, INF):
        cases[f"ico_vertex{vs:g}"] = (ICO, dict(corners=([0], [vs])))
        cases[f"ico_vertex{vs:g}_edge0.5"] = (ICO, dict(corners=([0], [vs]), creases=(PATH[:1], [0.5])))
        cases[f"ico_vertex{vs:g}_on_crease"] = (ICO, dict(corners=([1], [vs]), creases=(PATH[:2], [1.5, INF])))
        for b in oracle.BOUNDARY_RULES:   # one-face corner 0, two-face corner 4, boundary 2, interior 12
            cases[f"grid_vertex{vs:g}_{b}"] = (GRID, dict(corners=([0, 4, 2, 12], [vs, vs, vs, 0.75]), boundary=b))
    for b in oracle.BOUNDARY_RULES:
        cases[f"grid_{b}"] = (GRID, dict(boundary=b))
        cases[f"grid_creases_{b}"] = (GRID, dict(boundary=b, creases=(np.array([[0, 1], [1, 2], [2, 7], [7, 12]]),
                                                                      [INF, 0.5, 1.5, 0.5])))
        for n in (1, 3):
            cases[f"fan{n}_{b}"] = (meshes.open_fan(n), dict(boundary=b))
    cases["grid_none_boundary_inf"] = (GRID, dict(boundary="none", creases=GRID_BOUNDARY))
    return cases


CASES = _cases()


def lagrange_refine(V, F, n_levels: int, creases=None, corners=None, boundary="edge_and_corner",
                    limit: bool = False):
    """Return (points (n, 3), faces (m, 3)) of ``n_levels`` Loop steps by OpenSubdiv through lagrange.

    ``limit`` pushes the points of the last level to the limit surface.
    """
    mesh = lagrange.SurfaceMesh()
    mesh.add_vertices(np.asarray(V, dtype=np.float64))
    mesh.add_triangles(np.asarray(F, dtype=np.uint32))
    options = {}
    given = oracle.parse_creases(creases)
    if given:
        mesh.initialize_edges()
        s = [min(given.get(oracle.edge_key(*map(int, mesh.get_edge_vertices(e))), 0.0), 10.0) / 10.0
             for e in range(mesh.num_edges)]      # lagrange hands 10 * value to OpenSubdiv
        options["edge_sharpness_attr"] = mesh.create_attribute(
            "edge_sharpness", element=lagrange.AttributeElement.Edge, usage=lagrange.AttributeUsage.Scalar,
            initial_values=np.array(s, dtype=np.float64))
    if corners is not None:
        s = np.zeros(len(V))
        for v, x in oracle.parse_corners(corners).items():
            s[v] = min(x, 10.0) / 10.0
        options["vertex_sharpness_attr"] = mesh.create_attribute(
            "vertex_sharpness", element=lagrange.AttributeElement.Vertex, usage=lagrange.AttributeUsage.Scalar,
            initial_values=s)
    out = lagrange.subdivision.subdivide_mesh(
        mesh, num_levels=n_levels, scheme=lagrange.subdivision.SchemeType.Loop,
        vertex_boundary_interpolation=LAGRANGE_BOUNDARY[boundary], use_limit_surface=limit, **options)
    return np.array(out.vertices), np.array(out.facets, dtype=np.int64)


def match_vertices(P, faces, h, Q) -> np.ndarray:
    """Return, for every lagrange point, the oracle vertex at the same place (-1 if in no face).

    ``Q`` (n_L, 3) are the oracle's points of the last level of ``h``. Checks
    that the match is one to one and maps lagrange's faces onto the oracle's
    faces outside ``h.holes`` (fine face i of level L descends from control
    face i // 4^L).
    """
    L, level = len(h.levels) - 1, h.levels[-1]
    used = np.unique(faces)
    nearest = np.linalg.norm(P[used, None, :] - Q[None, :, :], axis=2).argmin(axis=1)
    assert len(set(nearest.tolist())) == len(used), "two lagrange points match one oracle vertex"
    to_oracle = -np.ones(len(P), dtype=np.int64)
    to_oracle[used] = nearest
    holes = set(h.holes.tolist())
    expected = {frozenset(f) for i, f in enumerate(level.F) if i // 4 ** L not in holes}
    assert {frozenset(to_oracle[f].tolist()) for f in faces} == expected
    return to_oracle


def oracle_hierarchy(mesh, n_levels: int, **kw):
    """Return the oracle hierarchy of a test mesh for the keywords of a case (uniform creasing)."""
    return oracle.subdivide(mesh.F, len(mesh.V), kw.get("creases"), n_levels, corners=kw.get("corners"),
                            boundary=kw.get("boundary", "edge_and_corner"))


def n_levels_of(kw) -> int:
    """At least two steps, and enough for every semi-sharp tag to expire (at most 5: the cases are small)."""
    L = max(2, oracle.levels_to_expire(kw.get("creases"), kw.get("corners")))
    assert L <= 5, f"a case needs {L} levels: is a sharpness >= 10 not taken as infinite?"
    return L


@pytest.mark.parametrize("name", list(CASES))
def test_refined_points_match_opensubdiv(name):
    mesh, kw = CASES[name]
    L = n_levels_of(kw)
    h = oracle_hierarchy(mesh, L, **kw)
    Q = h.S_total[-1] @ mesh.V
    P, faces = lagrange_refine(mesh.V, mesh.F, L, **kw)
    to_oracle = match_vertices(P, faces, h, Q)
    used = to_oracle >= 0
    np.testing.assert_allclose(P[used], Q[to_oracle[used]],
                               rtol=0, atol=TOL * np.ptp(mesh.V, axis=0).max())


@pytest.mark.parametrize("name", list(CASES))
def test_limit_points_match_opensubdiv(name):
    """Limit masks by rule (smooth, crease, corner) after expiry; darts are compared in the refinement test."""
    mesh, kw = CASES[name]
    L = n_levels_of(kw)
    h = oracle_hierarchy(mesh, L, **kw)
    refined, faces = lagrange_refine(mesh.V, mesh.F, L, **kw)
    to_oracle = match_vertices(refined, faces, h, h.S_total[-1] @ mesh.V)
    P, _ = lagrange_refine(mesh.V, mesh.F, L, limit=True, **kw)      # same vertex order
    limit = oracle.limit_rows(h) @ mesh.V
    level = h.levels[-1]
    keep = np.array([v >= 0 and level.vertex_kind(v) != "dart" for v in to_oracle])
    np.testing.assert_allclose(P[keep], limit[to_oracle[keep]], rtol=0, atol=TOL * np.ptp(mesh.V, axis=0).max())


@pytest.mark.parametrize(("name", "wrong"), [
    ("ico_edge0.5", dict(creases=(PATH[:1], [0.75]))),
    ("ico_edge2.25", dict(creases=(PATH[:1], [2.0]))),
    ("ico_vertex0.5", dict(corners=([0], [0.25]))),
    ("ico_loop_mixed", dict(creases=(PATH, [1.5, 0.5, 2.25, 3.0, 1.0, INF]))),
    ("grid_edge_only", dict(boundary="edge_and_corner")),
    ("fan1_edge_only", dict(boundary="edge_and_corner")),
], ids=["edge0.5_as_0.75", "edge2.25_as_2", "vertex0.5_as_0.25", "loop_1.25_as_1", "grid_boundary_rule",
        "fan1_boundary_rule"])
def test_comparison_tells_neighbouring_rules_apart(name, wrong):
    """The oracle with a nearby wrong tag misses OpenSubdiv by far more than the tolerance."""
    mesh, kw = CASES[name]
    L = n_levels_of(kw)
    P, _ = lagrange_refine(mesh.V, mesh.F, L, **kw)
    Q = oracle_hierarchy(mesh, L, **{**kw, **wrong}).S_total[-1] @ mesh.V
    miss = np.linalg.norm(P[:, None, :] - Q[None, :, :], axis=2).min(axis=1).max()
    assert miss > 1e-4 * np.ptp(mesh.V, axis=0).max()


def test_sharpness_of_ten_or_more_is_infinite():
    """SHARPNESS_INFINITE = 10: edge and vertex sharpness >= 10 never decay; below 10 they do."""
    creases = oracle.parse_creases((PATH[:3], [10.0, 12.0, 9.75]))
    assert [creases[oracle.edge_key(*e)] for e in PATH[:3]] == [INF, INF, 9.75]
    assert oracle.parse_corners(([0, 1], [10.0, 0.5])) == {0: INF, 1: 0.5}
    assert oracle.levels_to_expire((PATH[:2], [10.0, 2.25]), ([0], [12.0])) == 3


def test_hole_faces_under_boundary_none():
    """Faces at boundary vertices with a boundary edge not explicitly infinite are holes (only under 'none')."""
    F = GRID.F
    ring = {f for f, face in enumerate(F) if set(face.tolist()) & set(GRID_BOUNDARY.ravel().tolist())}
    np.testing.assert_array_equal(oracle.hole_faces(F, 20, None, "none"), sorted(ring))
    assert len(oracle.hole_faces(F, 20, GRID_BOUNDARY, "none")) == 0
    assert len(oracle.hole_faces(F, 20, None, "edge_only")) == 0
    # Only boundary edge 1-2 left semi-sharp: the faces at 1 and 2 stay holes, the rest not.
    partial = oracle.hole_faces(F, 20, (GRID_BOUNDARY, np.where(np.arange(14) == 1, 5.0, INF)), "none")
    around = {f for f, face in enumerate(F) if set(face.tolist()) & {1, 2}}
    np.testing.assert_array_equal(partial, sorted(around))


# --------------------------------------------------------------------------
# Hand-derived cases: the rules lagrange cannot express (Chaikin) and a check of the weights themselves
# --------------------------------------------------------------------------

LATTICE_F = meshes.grid_faces(5, 5)    # vertex 12 is regular, ring 7, 8, 11, 13, 16, 17; 11-12-13 a line


def test_chaikin_child_sharpness_averages_the_other_semi_sharp_edges():
    """Child = 3/4 s + 1/4 mean(other semi-sharp at the end vertex) - 1; inf edges are left out of the mean."""
    creases = (np.array([[11, 12], [12, 13], [7, 12]]), [1.5, 2.5, INF])
    expected = {"chaikin": {(11, 12): (0.5, 0.75), (12, 13): (1.25, 1.5)},
                "uniform": {(11, 12): (0.5, 0.5), (12, 13): (1.5, 1.5)}}
    for method, edges in expected.items():
        level = oracle.control_level(LATTICE_F, 25, creases, crease_method=method)
        fine, _, edge_vertex = oracle.subdivide_once(level)
        for (a, b), (at_a, at_b) in edges.items():
            m = edge_vertex[(a, b)]
            got = (fine.sharpness[oracle.edge_key(a, m)], fine.sharpness[oracle.edge_key(m, b)])
            np.testing.assert_allclose(got, (at_a, at_b), rtol=0, atol=1e-15, err_msg=f"{method} {a}-{b}")
        assert fine.sharpness[oracle.edge_key(12, edge_vertex[(7, 12)])] == INF


def test_semi_sharp_half_edge_point_is_half_midpoint_half_smooth():
    """s = 0.5 on a lattice edge: both children smooth, weight 0.5 (both methods)."""
    for method in oracle.CREASE_METHODS:
        S, _, edge_vertex = oracle.one_step_matrix(LATTICE_F, 25, (np.array([[11, 12]]), [0.5]), crease_method=method)
        c, d = oracle.control_level(LATTICE_F, 25).opposite[(11, 12)]
        row = S[edge_vertex[(11, 12)]].toarray().ravel()
        expected = np.zeros(25)
        expected[[11, 12]] = 0.5 * 0.5 + 0.5 * 3 / 8
        expected[[c, d]] = 0.5 * 1 / 8
        np.testing.assert_allclose(row, expected, rtol=0, atol=1e-15)


def _vertex_row(w_crease: float) -> np.ndarray:
    """w (3/4 v + 1/8 (p11 + p13)) + (1 - w) (5/8 v + 1/16 ring) at lattice vertex 12."""
    row = np.zeros(25)
    row[[7, 8, 11, 13, 16, 17]] = (1 - w_crease) / 16
    row[[11, 13]] += w_crease / 8
    row[12] = w_crease * 3 / 4 + (1 - w_crease) * 5 / 8
    return row


def test_chaikin_and_uniform_transition_weights_at_a_vertex():
    """Edges 11-12 (s = 1.25) and 12-13 (s = 0.25): a crease vertex whose children differ by method.

    Chaikin: both children at 12 are smooth (3/4 1.25 + 1/4 0.25 - 1 = 0), the
    child rule is smooth and the weight the mean of both, 0.75. Uniform: the
    children are 0.25 and 0, the child is a dart and only s = 0.25 decays, so
    the weight is 0.25.
    """
    creases = (np.array([[11, 12], [12, 13]]), [1.25, 0.25])
    for method, w in (("chaikin", 0.75), ("uniform", 0.25)):
        S, _, _ = oracle.one_step_matrix(LATTICE_F, 25, creases, crease_method=method)
        np.testing.assert_allclose(S[12].toarray().ravel(), _vertex_row(w), rtol=0, atol=1e-15, err_msg=method)


def test_chaikin_edge_weight_is_the_unclamped_parent_sharpness():
    """Edge 11-12 of s = 1.25 under chaikin: its child at 12 is smooth, at 11 it is 0.25 (dart).

    Far passes the child rule (dart) to ComputeEdgeVertexMask, which then
    blends with the parent sharpness 1.25 unclamped: 1.25 midpoint - 0.25
    smooth, so the opposite vertices get -1/32. Uniform keeps both children
    at 0.25: a crease, the midpoint. (Checked against OpenSubdiv 3.6 Far built
    from source: refined points agree to 1e-16.)
    """
    creases = (np.array([[11, 12], [12, 13]]), [1.25, 0.25])
    c, d = oracle.control_level(LATTICE_F, 25).opposite[(11, 12)]
    for method, w in (("chaikin", 1.25), ("uniform", 1.0)):
        S, _, edge_vertex = oracle.one_step_matrix(LATTICE_F, 25, creases, crease_method=method)
        expected = np.zeros(25)
        expected[[11, 12]] = w * 0.5 + (1 - w) * 3 / 8
        expected[[c, d]] = (1 - w) / 8
        np.testing.assert_allclose(S[edge_vertex[(11, 12)]].toarray().ravel(), expected, rtol=0, atol=1e-15,
                                   err_msg=method)


def test_vertex_sharpness_rules_and_limit_masks():
    """Interior vertex sharpness: corner while sharp, blended when it decays; limit masks by rule."""
    level = oracle.control_level(LATTICE_F, 25, corners=([12], [0.5]))
    assert level.vertex_kind(12) == "corner"
    S, _, _ = oracle.one_step_matrix(LATTICE_F, 25, corners=([12], [0.5]))
    expected = _vertex_row(0.0)
    expected = 0.5 * np.eye(25)[12] + 0.5 * expected     # corner -> smooth, weight 0.5
    np.testing.assert_allclose(S[12].toarray().ravel(), expected, rtol=0, atol=1e-15)
    assert oracle.limit_mask(oracle.control_level(LATTICE_F, 25, corners=[12]), 12) == {12: 1.0}
    # One-face corner: a corner under edge_and_corner, a crease under edge_only and none.
    for boundary, kind in (("edge_and_corner", "corner"), ("edge_only", "crease"), ("none", "crease")):
        level = oracle.control_level(LATTICE_F, 25, boundary=boundary)
        assert level.vertex_kind(0) == kind, boundary
    mask = oracle.limit_mask(oracle.control_level(LATTICE_F, 25, boundary="edge_only"), 0)
    assert mask == {0: 2 / 3, 1: 1 / 6, 5: 1 / 6}


def test_limit_rows_refuse_unexpired_tags():
    for kw in (dict(creases=(np.array([[11, 12]]), [1.5])), dict(corners=([12], [1.5]))):
        h = oracle.subdivide(LATTICE_F, 25, kw.get("creases"), 1, corners=kw.get("corners"))
        with pytest.raises(ValueError, match="finite sharpness"):
            oracle.limit_rows(h)
    with pytest.raises(ValueError, match="crease_method"):
        oracle.control_level(LATTICE_F, 25, crease_method="chaikn")
    with pytest.raises(ValueError, match="boundary"):
        oracle.control_level(LATTICE_F, 25, boundary="corner")
