"""mi_loop's subdivision and exact limit under OpenSubdiv's whole crease model, against the independent oracle.

``tests/oracle_loop.py`` implements the Sdc rules one vertex at a time (and is
itself checked against OpenSubdiv in ``test_oracle_opensubdiv.py``). Here every
rule is exercised on meshes with extraordinary vertices and boundaries:
fractional and large edge sharpness, vertex sharpness (interior and on the
boundary), Chaikin with unequal neighbours, and the three boundary rules.

- one step: ``subdivision_matrix`` equals the oracle's row for row (1e-14);
- the limit: ``limit_matrix`` at every dyadic point of the oracle's refinement
  (past the expiry of every semi-sharp tag) equals the oracle's limit rows to
  1e-10 of the bounding-box diagonal, positions in a random control mesh;
  derivative rows are checked by their defining property against positions at
  nearby parameters (finite differences).
"""
from __future__ import annotations

import numpy as np
import pytest

import mi_loop

import oracle_loop as oracle
from meshes import grid, icosahedron, open_fan

# (mesh builder, keyword model); edges and vertices are picked by index from each mesh.


def _edges(F, picks):
    E = []
    for f, c in picks:
        E.append([int(F[f, c]), int(F[f, (c + 1) % 3])])
    return np.array(E)


def _cases():
    ico = icosahedron()
    g = grid(6, 5)
    fan = open_fan(5)
    chain = _edges(ico.F, [(0, 0), (0, 1), (3, 0)])
    out = []
    out.append(("ico-fractional", ico, dict(creases=(chain, [0.5, 2.25, 1.5]))))
    out.append(("ico-large-sharpness", ico, dict(creases=(chain, [5.0, 12.0, 3.75]))))
    out.append(("ico-chaikin", ico, dict(creases=(chain, [2.5, 0.75, 1.25]), crease_method="chaikin")))
    out.append(("ico-vertex-sharpness", ico, dict(corners=([0, 5], [0.5, 2.0]))))
    out.append(("ico-infinite-corner", ico, dict(corners=[3], creases=(chain[:1], [1.5]))))
    out.append(("ico-dart-and-corner", ico, dict(creases=chain[:1], corners=([int(ico.F[7, 0])], [1.25]))))
    boundary_chain = _edges(g.F, [(0, 0), (1, 2)])
    for rule in ("edge_and_corner", "edge_only", "none"):
        out.append((f"grid-{rule}", g, dict(boundary=rule, creases=(boundary_chain, [1.5, 0.5]))))
    out.append(("grid-corner-on-boundary", g, dict(corners=([2, 7], [0.75, np.inf]), boundary="edge_only")))
    out.append(("grid-chaikin-edge-only", g, dict(creases=(boundary_chain, [2.0, 0.5]), crease_method="chaikin",
                                                  boundary="edge_only")))
    out.append(("fan-edge-only", fan, dict(boundary="edge_only")))
    out.append(("fan-none-sharp-boundary", fan, dict(boundary="none",
                                                     creases=_boundary_edges(fan.F, len(fan.V)))))
    return out


def _boundary_edges(F, n):
    from mi_loop.mesh.halfedge import Topology

    t = Topology.build(F, n)
    return t.E[t.boundary]


CASES = _cases()
IDS = [c[0] for c in CASES]


@pytest.mark.parametrize("name, mesh, model", CASES, ids=IDS)
def test_one_step_equals_the_oracle(name, mesh, model):
    from mi_loop.mesh.halfedge import Topology

    n = len(mesh.V)
    S, _ = mi_loop.subdivision_matrix(mesh.F, n, **model)
    S_ref, _, edge_vertex_ref = oracle.one_step_matrix(mesh.F, n, **model)
    to_ref = np.arange(S.shape[0])              # mi_loop: fine vertex n + i is the point of sorted edge i
    for i, (a, b) in enumerate(Topology.build(mesh.F, n).E):
        to_ref[n + i] = edge_vertex_ref[(int(a), int(b))]
    np.testing.assert_allclose(S.toarray(), S_ref.toarray()[to_ref], rtol=0, atol=1e-14, err_msg=name)


@pytest.mark.parametrize("name, mesh, model", CASES, ids=IDS)
def test_limit_at_dyadic_points_equals_the_oracle(name, mesh, model):
    n = len(mesh.V)
    levels = oracle.levels_to_expire(model.get("creases"), model.get("corners")) + 2
    h = oracle.subdivide(mesh.F, n, n_levels=levels, **model)
    W_ref = oracle.limit_rows(h)
    face_ids, uv, vertex = oracle.dyadic_samples(h)
    assert len(face_ids) > 0
    W = mi_loop.limit_matrix(mesh.F, n, face_ids, uv, **model).toarray()
    V = np.random.default_rng(5).standard_normal((n, 3))
    diag = np.linalg.norm(V.max(0) - V.min(0))
    err = np.abs(W @ V - W_ref[vertex] @ V).max() / diag
    assert err < 1e-10, (name, err)


@pytest.mark.parametrize("name, mesh, model", CASES, ids=IDS)
def test_derivatives_are_those_of_the_positions(name, mesh, model):
    """d/du and d/dv rows against central differences of positions inside faces (away from corners)."""
    from mi_loop.mesh.topology import sharp_topology

    n = len(mesh.V)
    hole = sharp_topology(mesh.F, n, "test", **model).hole
    faces = np.flatnonzero(~hole)
    rng = np.random.default_rng(1)
    f = rng.choice(faces, 40)
    uv = rng.uniform(0.15, 0.4, (40, 2))
    V = rng.standard_normal((n, 3))
    eps = 1e-6
    for k, d in enumerate(("u", "v")):
        step = np.zeros(2)
        step[k] = eps
        Wd = mi_loop.limit_matrix(mesh.F, n, f, uv, derivative=d, **model)
        plus = mi_loop.limit_matrix(mesh.F, n, f, uv + step, **model) @ V
        minus = mi_loop.limit_matrix(mesh.F, n, f, uv - step, **model) @ V
        np.testing.assert_allclose(Wd @ V, (plus - minus) / (2 * eps), rtol=0, atol=2e-6, err_msg=f"{name} {d}")


def test_cases_exercise_every_rule():
    """The premise: these models reach the blends, Chaikin, corners and holes they are named after."""
    from mi_loop.mesh.topology import sharp_topology

    kinds = set()
    for _name, mesh, model in CASES:
        t = sharp_topology(mesh.F, len(mesh.V), "test", **model)
        s = t.sharpness[np.isfinite(t.sharpness) & (t.sharpness > 0)]
        if (s % 1 != 0).any():
            kinds.add("fractional")
        if (t.vertex_sharpness > 0).any():
            kinds.add("vertex sharpness")
        if t.hole.any():
            kinds.add("holes")
        if t.crease_method == "chaikin":
            kinds.add("chaikin")
    assert kinds == {"fractional", "vertex sharpness", "holes", "chaikin"}
