"""The smallest control meshes: exact limits and derivatives, or a clear refusal.

Each mesh below is either evaluated exactly (positions at every dyadic point
against iterated subdivision, ``tests/oracle_loop.py``; d/du and d/dv against
the oracle's exact five-point derivatives on polynomial sub-patches; vertex
masks against the oracle's limit rows) or refused by ``validate_mesh`` with a
message that names the problem. The closed two-triangle mesh
``[[0, 1, 2], [0, 2, 1]]`` is refused: its refinement has two distinct edges
between the same two vertices at every level (around its valence-2
vertices), which neither mi_loop's vertex-indexed topology nor the oracle's
edge dictionary can hold, and its limit surface is degenerate (see
``test_double_triangle_limit_is_degenerate``).
"""
from __future__ import annotations

import functools
import re

import numpy as np
import pytest

import mi_loop
from mi_loop.subdiv.masks import tangent_masks

import meshes
import oracle_loop as oracle
from helpers import bbox_diagonal

TET = meshes.tetrahedron()


def tiny_meshes() -> dict:
    """Closed and open meshes with 1 to 6 faces, valence-2 corners and valence-3 vertices."""
    out = {m.name: m for m in (TET, meshes.bipyramid(3), meshes.open_fan(1), meshes.open_fan(2),
                               meshes.open_fan(3), meshes.fan_disc(3))}
    # Tetrahedron without one face: open, three boundary vertices of valence 3, apex of valence 3.
    out["tet_open"] = meshes.TestMesh("tet_open", TET.V, TET.F[1:])
    # Two triangles back to back along one edge, the rest boundary: a bent two-triangle strip.
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0.4, 0.9, 0.1], [0.6, -0.8, 0.3]])
    out["strip2"] = meshes.TestMesh("strip2", V, np.array([[0, 1, 2], [1, 0, 3]]))
    # The tetrahedron with one infinitely sharp edge (darts at both ends) and with all six edges sharp.
    out["tet_crease"] = meshes.TestMesh("tet_crease", TET.V, TET.F, np.array([[0, 1]]))
    edges = np.unique(np.sort(np.concatenate([TET.F[:, [0, 1]], TET.F[:, [1, 2]], TET.F[:, [2, 0]]]), 1), axis=0)
    out["tet_all_sharp"] = meshes.TestMesh("tet_all_sharp", TET.V, TET.F, edges)
    return out


TINY = tiny_meshes()


@functools.cache
def reference(name: str, levels: int = 4):
    mesh = TINY[name]
    h = oracle.subdivide(mesh.F, len(mesh.V), mesh.creases, levels)
    return h, oracle.limit_rows(h)


def without_darts(h, face_ids, uv, vertex):
    """Samples whose finest-level vertex is not a dart (the oracle's mask there is the eigenvector one)."""
    keep = np.array([h.levels[-1].vertex_kind(v) != "dart" for v in vertex])
    return face_ids[keep], uv[keep], vertex[keep]


@pytest.mark.parametrize("name", list(TINY))
def test_positions_at_every_dyadic_point(name):
    mesh = TINY[name]
    h, W_ref = reference(name)
    face_ids, uv, vertex = oracle.dyadic_samples(h)
    face_ids, uv, vertex = without_darts(h, face_ids, uv, vertex)
    W = mi_loop.limit_matrix(mesh.F, len(mesh.V), face_ids, uv, creases=mesh.creases)
    P, P_ref = W @ mesh.V, W_ref[vertex] @ mesh.V
    np.testing.assert_allclose(P, P_ref, rtol=0, atol=1e-10 * bbox_diagonal(mesh.V), err_msg=name)
    np.testing.assert_allclose(W.toarray(), W_ref[vertex], rtol=0, atol=1e-10, err_msg=name)


@pytest.mark.parametrize("name", list(TINY))
def test_derivatives_on_polynomial_sub_patches(name):
    """d/du, d/dv against the oracle's exact five-point stencil on level-2 sub-patches (h = 1/32)."""
    mesh = TINY[name]
    h, _ = reference(name, 5)
    face_ids, uv, du_ref, dv_ref = oracle.polynomial_derivatives(h, mesh.V, patch_level=2)
    assert len(face_ids) >= 20 * len(mesh.F)
    tol = 1e-10 * bbox_diagonal(mesh.V) * 2 ** 5
    for d, ref in (("u", du_ref), ("v", dv_ref)):
        ok = np.isfinite(ref).all(1)
        D = mi_loop.limit_matrix(mesh.F, len(mesh.V), face_ids[ok], uv[ok], creases=mesh.creases, derivative=d)
        np.testing.assert_allclose(D @ mesh.V, ref[ok], rtol=0, atol=tol, err_msg=f"{name} d/d{d}")


def test_derivative_oracle_can_fail():
    """The stencil sees a wrong derivative: d/du of the tetrahedron is not d/dv, nor d/du scaled."""
    h, _ = reference("tetrahedron", 5)
    face_ids, uv, du_ref, dv_ref = oracle.polynomial_derivatives(h, TET.V, patch_level=2)
    ok = np.isfinite(du_ref).all(1) & np.isfinite(dv_ref).all(1)
    D = mi_loop.limit_matrix(TET.F, 4, face_ids[ok], uv[ok], derivative="v") @ TET.V
    assert np.abs(D - du_ref[ok]).max() > 1e-2
    assert np.abs(1.01 * D - dv_ref[ok]).max() > 1e-4


@pytest.mark.parametrize("name", list(TINY))
def test_vertex_masks_agree(name):
    """limit_positions, limit_masks and tangent_masks against the oracle and limit_matrix at the corners."""
    mesh = TINY[name]
    n = len(mesh.V)
    h, W_ref = reference(name)
    kinds = [h.levels[-1].vertex_kind(v) for v in range(n)]
    exact = [v for v in range(n) if kinds[v] != "dart"]
    M = mi_loop.limit_masks(mesh.F, n, creases=mesh.creases)
    np.testing.assert_allclose(M.toarray()[exact], W_ref[exact], rtol=0, atol=1e-12, err_msg=name)
    P = mi_loop.limit_positions(mesh.V, mesh.F, creases=mesh.creases)
    np.testing.assert_allclose(P, M @ mesh.V, rtol=0, atol=1e-14 * bbox_diagonal(mesh.V))
    from mi_loop.subdiv.masks import vertex_samples

    face_ids, uv = vertex_samples(mesh.F, n)
    np.testing.assert_allclose(M.toarray(), mi_loop.limit_matrix(mesh.F, n, face_ids, uv, mesh.creases).toarray(),
                               rtol=0, atol=1e-12)
    for D, d in zip(tangent_masks(mesh.F, n, creases=mesh.creases), "uv"):
        row = mi_loop.limit_matrix(mesh.F, n, face_ids, uv, creases=mesh.creases, derivative=d)
        np.testing.assert_allclose(D.toarray(), row.toarray(), rtol=0, atol=1e-12, err_msg=f"{name} d/d{d}")


def test_single_triangle_corners_interpolate():
    """A lone triangle: its three vertices are corners, so the limit passes through them."""
    mesh = TINY["open_fan1"]
    np.testing.assert_allclose(mi_loop.limit_positions(mesh.V, mesh.F), mesh.V, rtol=0, atol=1e-15)


DOUBLE = ("expected no two faces on the same three vertices, got faces 0 = [0, 1, 2] and 1 = [0, 2, 1]: "
          "a closed two-triangle component, whose limit surface is flat and doubly covered and whose "
          "refinement has double edges; remove it")
V3 = np.array([[0.0, 0, 0], [1, 0, 0], [0.2, 0.9, 0.3]])
F2 = np.array([[0, 1, 2], [0, 2, 1]])


def test_double_triangle_refused_everywhere():
    """The issue's mesh passes no public entry point, and each names itself and both faces."""
    calls = {
        "validate_mesh": lambda: mi_loop.validate_mesh(V3, F2),
        "subdivision_matrix": lambda: mi_loop.subdivision_matrix(F2, 3),
        "limit_matrix": lambda: mi_loop.limit_matrix(F2, 3, [0], [[0.25, 0.25]]),
        "limit_positions": lambda: mi_loop.limit_positions(V3, F2),
        "limit_normals": lambda: mi_loop.limit_normals(V3, F2),
        "limit_masks": lambda: mi_loop.limit_masks(F2, 3),
        "tessellate": lambda: mi_loop.tessellate(F2, 2),
    }
    for name, call in calls.items():
        with pytest.raises(ValueError, match="^" + re.escape(f"{name}(): {DOUBLE}") + "$"):
            call()


def test_double_triangle_limit_is_degenerate():
    """Why it is refused, checked on its refinement (by the oracle, which knows nothing of the refusal).

    One step gives faces in pairs on the same three vertices (the two copies
    of each child) and edges between child corners used by four faces: two
    distinct edges of the surface with the same end vertices, which no
    vertex-indexed mesh can hold (validate_mesh calls it non-manifold). And
    the surface is flat: every refined point is an affine combination of the
    three control points.
    """
    level = oracle.control_level(F2, 3)
    fine, rows, _ = oracle.subdivide_once(level)
    _, counts = np.unique(np.sort(np.array(fine.F), 1), axis=0, return_counts=True)
    assert counts.tolist() == [2, 2, 2, 2]
    assert max(len(o) for o in fine.opposite.values()) == 4
    points = oracle.rows_to_csr(rows, fine.n, 3) @ V3
    with pytest.raises(ValueError, match=r"non-manifold edge \(\d, \d\) shared by 4 faces"):
        mi_loop.validate_mesh(points, np.array(fine.F))
    normal = np.cross(V3[1] - V3[0], V3[2] - V3[0])
    np.testing.assert_allclose((points - V3[0]) @ normal, 0, atol=1e-15)


def random_small_meshes(count: int, seed: int = 0):
    """Random face subsets of small closed meshes, with random infinite or sharpness-1 creases."""
    rng = np.random.default_rng(seed)
    bases = [meshes.tetrahedron(), meshes.octahedron(), meshes.bipyramid(3), meshes.bipyramid(4),
             meshes.bipyramid(5), meshes.icosahedron()]
    for k in range(count):
        base = bases[k % len(bases)]
        F = base.F[rng.random(len(base.F)) < rng.uniform(0.4, 1.0)]
        if len(F) == 0:
            F = base.F[:1]
        used = np.unique(F)
        remap = np.full(len(base.V), -1)
        remap[used] = np.arange(len(used))
        F, V = remap[F], base.V[used]
        edges = np.unique(np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), 1), axis=0)
        E = edges[rng.random(len(edges)) < 0.2]
        creases = None if len(E) == 0 else (E, rng.choice([1.0, np.inf], size=len(E)))
        yield meshes.TestMesh(f"random{k}", V, F, creases)


def test_random_small_meshes_work_or_are_refused():
    """Every random small mesh is either refused by validate_mesh (one-line message) or exact at dyadic points."""
    worked, refused = 0, 0
    for mesh in random_small_meshes(36):
        try:
            mi_loop.validate_mesh(mesh.V, mesh.F)
        except ValueError as exc:
            assert re.fullmatch(r"validate_mesh\(\): expected [^\n]+, got [^\n]+", str(exc)), str(exc)
            refused += 1
            continue
        h = oracle.subdivide(mesh.F, len(mesh.V), mesh.creases, 3)
        W_ref = oracle.limit_rows(h)
        face_ids, uv, vertex = without_darts(h, *oracle.dyadic_samples(h))
        W = mi_loop.limit_matrix(mesh.F, len(mesh.V), face_ids, uv, creases=mesh.creases)
        np.testing.assert_allclose(W @ mesh.V, W_ref[vertex] @ mesh.V, rtol=0,
                                   atol=1e-10 * bbox_diagonal(mesh.V), err_msg=f"{mesh.name}: F = {mesh.F.tolist()}")
        worked += 1
    assert worked >= 15 and refused >= 3, (worked, refused)
