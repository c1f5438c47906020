"""Exact limit evaluation: ``mi_loop.limit_matrix`` against iterated subdivision.

Ground truth (``tests/oracle_loop.py``): four Loop steps, then the limit mask
at every vertex of level 4, gives the exact limit point at every dyadic
parameter (i/16, j/16) of every control face. Every such point must match
``limit_matrix`` to 1e-10 of the bounding-box diagonal. Further checks:
row sums, derivatives against central differences, C1 continuity across
every shared control edge, polynomial reproduction on a planar regular
lattice, and the vertex-only functions ``limit_positions`` / ``limit_normals``.
"""
from __future__ import annotations

import functools
import math

import numpy as np
import pytest
import scipy.sparse as sp

import mi_loop

import meshes
import oracle_loop as oracle
from helpers import bbox_diagonal

MESH_NAMES = list(meshes.MESHES)
N_LEVELS = 4  # all finite sharpness in the test meshes is <= 4


@functools.cache
def reference(name: str):
    """Return (hierarchy, exact limit rows (n_L, n), face_ids, uv, vertex) of a test mesh."""
    mesh = meshes.MESHES[name]
    h = oracle.subdivide(mesh.F, len(mesh.V), mesh.creases, N_LEVELS)
    W = oracle.limit_rows(h)
    face_ids, uv, vertex = oracle.dyadic_samples(h)
    return h, W, face_ids, uv, vertex


def dart_free(name: str):
    """Return the dyadic samples whose level-4 vertex is not a dart (see test_dart_vertex_limit)."""
    h, W, face_ids, uv, vertex = reference(name)
    keep = np.array([h.levels[-1].vertex_kind(v) != "dart" for v in vertex])
    return W, face_ids[keep], uv[keep], vertex[keep]


def worst(err, face_ids, uv) -> str:
    i = int(np.argmax(err))
    return f"worst at face {face_ids[i]}, uv = ({uv[i, 0]!r}, {uv[i, 1]!r}): error {err[i]:.3e}"


def interior_samples(F, per_face: int, seed: int, margin: float = 0.1):
    """Return random (face_ids, uv) with all barycentric coordinates >= margin."""
    rng = np.random.default_rng(seed)
    face_ids = np.repeat(np.arange(len(F)), per_face)
    b = rng.dirichlet(np.ones(3), size=len(face_ids))
    b = margin + (1 - 3 * margin) * b
    return face_ids, b[:, 1:].copy()


# --------------------------------------------------------------------------
# The oracle itself
# --------------------------------------------------------------------------

@pytest.mark.slow
def test_oracle_masks_are_limit_eigenvectors():
    """Closed-form smooth/crease/corner masks = left eigenvector of the one-ring matrix."""
    for name in MESH_NAMES:
        h = reference(name)[0]
        level = h.levels[-1]
        for v in range(0, level.n, 7):
            if level.vertex_kind(v) == "dart":
                continue
            a, b = oracle.limit_mask(level, v), oracle.eigen_limit_mask(level, v)
            for w in set(a) | set(b):
                assert abs(a.get(w, 0.0) - b.get(w, 0.0)) < 1e-12, (name, v, w)


def test_oracle_regular_mask_and_rows():
    level = oracle.control_level(meshes.grid_faces(5, 5), 25)
    mask = oracle.limit_mask(level, 12)
    assert mask[12] == pytest.approx(0.5, abs=1e-15)
    np.testing.assert_allclose([mask[w] for w in level.neighbours[12]], np.full(6, 1 / 12), rtol=0, atol=1e-15)
    for name in MESH_NAMES:
        W = reference(name)[1]
        np.testing.assert_allclose(W.sum(axis=1), 1.0, rtol=0, atol=1e-13)
        assert W.min() > -1e-15


def test_oracle_boundary_is_cubic_bspline():
    """Between two boundary (crease) vertices the limit is the uniform cubic B-spline."""
    mesh = meshes.grid()
    nx = 6
    _, W, face_ids, uv, vertex = reference(mesh.name)
    L = W @ mesh.V
    checked = 0
    for f, (u, v), w in zip(face_ids, uv, vertex):
        a, b, _ = mesh.F[f]
        if v == 0 and b == a + 1 and 1 <= a <= nx - 3:  # bottom row, segment a..a+1
            P = mesh.V[a - 1:a + 3]
            B = ((1 - u) ** 3 * P[0] + (3 * u ** 3 - 6 * u ** 2 + 4) * P[1]
                 + (-3 * u ** 3 + 3 * u ** 2 + 3 * u + 1) * P[2] + u ** 3 * P[3]) / 6
            np.testing.assert_allclose(L[w], B, rtol=0, atol=1e-14)
            checked += 1
    assert checked == 3 * 17


def test_oracle_dart_mask_differs_from_smooth_mask():
    """At a dart the midpoint crease edge breaks the smooth mask's invariance (documented)."""
    mesh = meshes.icosahedron_dart()
    level = oracle.control_level(mesh.F, len(mesh.V), mesh.creases)
    assert level.vertex_kind(0) == "dart"
    k = 5
    chi = 1 / (3 / (8 * oracle.loop_beta(k)) + k)
    assert abs(oracle.eigen_limit_mask(level, 0)[0] - (1 - k * chi)) > 1e-2


# --------------------------------------------------------------------------
# Exact limit points
# --------------------------------------------------------------------------

@pytest.mark.parametrize("name", MESH_NAMES)
def test_limit_points_match_iterated_subdivision(name):
    """Every dyadic point (i/16, j/16) of every control face (all faces sharing it)."""
    mesh = meshes.MESHES[name]
    W_ref, face_ids, uv, vertex = dart_free(name)
    W = mi_loop.limit_matrix(mesh.F, len(mesh.V), face_ids, uv, creases=mesh.creases)
    assert sp.issparse(W) and W.format == "csr" and W.shape == (len(face_ids), len(mesh.V))

    P, P_ref = W @ mesh.V, W_ref[vertex] @ mesh.V
    err = np.linalg.norm(P - P_ref, axis=1)
    tol = 1e-10 * bbox_diagonal(mesh.V)
    np.testing.assert_allclose(P, P_ref, rtol=0, atol=tol, err_msg=f"{name}: {worst(err, face_ids, uv)}")
    # Weights as well: a wrong weight cannot hide behind a symmetric mesh.
    np.testing.assert_allclose(W.toarray(), W_ref[vertex], rtol=0, atol=1e-10, err_msg=name)


@pytest.mark.parametrize("name", ["ico_dart", "grid_dart", "mixed_sharpness"])
def test_dart_vertex_limit(name):
    """At a dart vertex the exact limit is the eigenvector mask of the rules (see oracle docs)."""
    mesh = meshes.MESHES[name]
    h, W_ref, face_ids, uv, vertex = reference(name)
    dart = np.array([h.levels[-1].vertex_kind(v) == "dart" for v in vertex])
    assert dart.any()
    W = mi_loop.limit_matrix(mesh.F, len(mesh.V), face_ids[dart], uv[dart], creases=mesh.creases)
    P, P_ref = W @ mesh.V, W_ref[vertex[dart]] @ mesh.V
    err = np.linalg.norm(P - P_ref, axis=1)
    np.testing.assert_allclose(P, P_ref, rtol=0, atol=1e-10 * bbox_diagonal(mesh.V),
                               err_msg=f"{name}: {worst(err, face_ids[dart], uv[dart])}")


@pytest.mark.parametrize("name", MESH_NAMES)
def test_row_sums(name):
    mesh = meshes.MESHES[name]
    _, face_ids, uv, _ = dart_free(name)
    for derivative, total in ((None, 1.0), ("u", 0.0), ("v", 0.0)):
        W = mi_loop.limit_matrix(mesh.F, len(mesh.V), face_ids, uv, creases=mesh.creases, derivative=derivative)
        sums = np.asarray(W.sum(axis=1)).ravel()
        # Derivative rows can be large near a valence > 6 vertex; scale by the row's size.
        scale = 1.0 + np.asarray(abs(W).sum(axis=1)).ravel()
        np.testing.assert_allclose(sums / scale, total / scale, rtol=0, atol=1e-12,
                                   err_msg=f"{name}, derivative={derivative}")


# --------------------------------------------------------------------------
# Derivatives
# --------------------------------------------------------------------------

@pytest.mark.parametrize("name", MESH_NAMES)
def test_derivatives_match_central_differences(name):
    """d/du, d/dv rows = (row(uv + h e) - row(uv - h e)) / 2h at points with barycentrics >= 0.1.

    Tolerance: the surface is piecewise polynomial (quartic box splines on
    sub-patches, C2 across them) and these points lie in sub-patches of level
    <= 4, where third parameter derivatives of the weights are below
    (8 lambda)^4 <= 5e2 (lambda <= 0.6 for valence <= 12). With h = 1e-5 the
    truncation error is <= h^2/6 * 5e2 ~ 1e-8 and rounding ~ 1e-16 / h = 1e-11,
    so 1e-6 (absolute, per weight) leaves two orders of margin; a wrong
    derivative is off by O(0.1) or more.
    """
    mesh = meshes.MESHES[name]
    n = len(mesh.V)
    face_ids, uv = interior_samples(mesh.F, 3, seed=len(name))
    step = 1e-5

    def rows(points, derivative=None):
        return mi_loop.limit_matrix(mesh.F, n, face_ids, points, creases=mesh.creases,
                                    derivative=derivative).toarray()

    for derivative, e in (("u", np.array([step, 0.0])), ("v", np.array([0.0, step]))):
        fd = (rows(uv + e) - rows(uv - e)) / (2 * step)
        D = rows(uv, derivative)
        err = abs(D - fd).max(axis=1)
        np.testing.assert_allclose(D, fd, rtol=0, atol=1e-6,
                                   err_msg=f"{name}, d/d{derivative}: {worst(err, face_ids, uv)}")


def no_finite_sharpness(name: str) -> bool:
    return not any(0 < s < math.inf for s in oracle.parse_creases(meshes.MESHES[name].creases).values())


@pytest.mark.parametrize("name", [m for m in MESH_NAMES if no_finite_sharpness(m)])
def test_derivatives_match_oracle_on_polynomial_patches(name):
    """d/du, d/dv = the oracle's exact five-point stencil (h = 1/16) on level-1 sub-patches.

    A level-1 sub-triangle without a control vertex is one quartic polynomial
    (see ``oracle.polynomial_derivatives``), so the stencil is exact there and
    the tolerance is rounding only: the stencil multiplies position errors
    (1e-10 of the diagonal) by at most 18 / (12 h) = 24.
    """
    mesh = meshes.MESHES[name]
    h = reference(name)[0]
    face_ids, uv, du_ref, dv_ref = oracle.polynomial_derivatives(h, mesh.V, patch_level=1)
    assert len(face_ids) >= 20 * len(mesh.F)
    for d, ref in (("u", du_ref), ("v", dv_ref)):
        ok = np.isfinite(ref).all(1)
        D = mi_loop.limit_matrix(mesh.F, len(mesh.V), face_ids[ok], uv[ok], creases=mesh.creases, derivative=d)
        err = np.linalg.norm(D @ mesh.V - ref[ok], axis=1)
        np.testing.assert_allclose(D @ mesh.V, ref[ok], rtol=0, atol=24e-10 * bbox_diagonal(mesh.V),
                                   err_msg=f"{name}, d/d{d}: {worst(err, face_ids[ok], uv[ok])}")


# --------------------------------------------------------------------------
# C1 across control edges
# --------------------------------------------------------------------------

def corner_uv(face, vertex):
    return {0: (0.0, 0.0), 1: (1.0, 0.0), 2: (0.0, 1.0)}[list(face).index(vertex)]


def infinite_crease_edges(creases) -> set:
    return {e for e, s in oracle.parse_creases(creases).items() if s == math.inf}


def edge_samples(F):
    """Return (faces f, faces g, uv in f, uv in g, is-edge ids) for points on every shared edge."""
    ts = np.r_[np.arange(1, 16) / 16, 0.01, 0.3711, 0.99]
    by_edge = {}
    for f, face in enumerate(np.asarray(F)):
        for i in range(3):
            by_edge.setdefault(oracle.edge_key(face[i], face[(i + 1) % 3]), []).append(f)
    rows = []
    for (a, b), faces in sorted(by_edge.items()):
        if len(faces) != 2:
            continue
        f, g = faces
        ua, ub = np.array(corner_uv(F[f], a)), np.array(corner_uv(F[f], b))
        wa, wb = np.array(corner_uv(F[g], a)), np.array(corner_uv(F[g], b))
        for t in ts:
            rows.append((f, g, (1 - t) * ua + t * ub, (1 - t) * wa + t * wb, (a, b)))
    f, g, uf, ug, e = zip(*rows)
    return np.array(f), np.array(g), np.array(uf), np.array(ug), list(e)


@pytest.mark.parametrize("name", [m for m in MESH_NAMES if len(meshes.MESHES[m].F) > 1])
def test_c1_across_control_edges(name):
    """Positions and unit normals cross(d/du, d/dv) agree from both faces of every shared edge.

    On infinitely sharp crease edges only positions must agree. Normals are
    compared to 1e-8: both sides are exact evaluations, and the derivatives
    at these points (never a control vertex) are bounded away from zero.
    """
    mesh = meshes.MESHES[name]
    n = len(mesh.V)
    f, g, uf, ug, edges = edge_samples(mesh.F)

    def evaluate(faces, uv):
        out = [mi_loop.limit_matrix(mesh.F, n, faces, uv, creases=mesh.creases, derivative=d) @ mesh.V
               for d in (None, "u", "v")]
        normal = np.cross(out[1], out[2])
        return out[0], normal / np.linalg.norm(normal, axis=1, keepdims=True)

    P_f, N_f = evaluate(f, uf)
    P_g, N_g = evaluate(g, ug)
    err = np.linalg.norm(P_f - P_g, axis=1)
    np.testing.assert_allclose(P_f, P_g, rtol=0, atol=1e-10 * bbox_diagonal(mesh.V),
                               err_msg=f"{name} positions: {worst(err, f, uf)}")
    smooth = np.array([e not in infinite_crease_edges(mesh.creases) for e in edges])
    err = np.linalg.norm(N_f - N_g, axis=1) * smooth
    np.testing.assert_allclose(N_f[smooth], N_g[smooth], rtol=0, atol=1e-8,
                               err_msg=f"{name} normals: {worst(err, f, uf)}")


# --------------------------------------------------------------------------
# Polynomial reproduction on a planar regular lattice
# --------------------------------------------------------------------------

LATTICE_H = 0.7
POLYNOMIALS = {
    # name: (f, Laplacian of f)
    "x2-y2": (lambda x, y: x * x - y * y, lambda x, y: 0 * x),
    "xy": (lambda x, y: x * y, lambda x, y: 0 * x),
    "x3-3xy2": (lambda x, y: x ** 3 - 3 * x * y * y, lambda x, y: 0 * x),
    "x2+y2": (lambda x, y: x * x + y * y, lambda x, y: 4 + 0 * x),
    "cubic": (lambda x, y: x ** 3 - 2 * x * y * y + 0.5 * y ** 3 + x * y - y,
              lambda x, y: 6 * x - 4 * x + 3 * y),
}


def lattice_interior_samples(nx=9, ny=8):
    """Planar lattice; dyadic and random points of faces whose three vertices are interior."""
    XY = meshes.lattice_points(nx, ny, LATTICE_H)
    F = meshes.grid_faces(nx, ny)
    i, j = np.arange(nx * ny) % nx, np.arange(nx * ny) // nx
    interior = (i > 0) & (i < nx - 1) & (j > 0) & (j < ny - 1)
    faces = np.flatnonzero(interior[F].all(axis=1))
    dyadic = np.array([(a / 8, b / 8) for a in range(9) for b in range(9 - a)])
    rng = np.random.default_rng(5)
    b = rng.dirichlet(np.ones(3), size=20)[:, 1:]
    uv = np.vstack([dyadic, b])
    face_ids = np.repeat(faces, len(uv))
    uv = np.tile(uv, (len(faces), 1))
    a_, b_, c_ = (XY[F[face_ids, k]] for k in range(3))
    p = (1 - uv.sum(axis=1))[:, None] * a_ + uv[:, :1] * b_ + uv[:, 1:] * c_
    return XY, F, face_ids, uv, p


def lattice_error(W, XY, f, lap, p):
    V = np.c_[XY, f(XY[:, 0], XY[:, 1])]
    L = W @ V
    expected = np.c_[p, f(p[:, 0], p[:, 1]) + LATTICE_H ** 2 / 8 * lap(p[:, 0], p[:, 1])]
    return L, expected


def test_oracle_polynomial_reproduction():
    """The oracle itself reproduces f + h^2/8 Laplacian(f) for cubics at dyadic points."""
    nx, ny = 9, 8
    XY = meshes.lattice_points(nx, ny, LATTICE_H)
    F = meshes.grid_faces(nx, ny)
    h = oracle.subdivide(F, len(XY), None, 3)
    W = oracle.limit_rows(h)
    face_ids, uv, vertex = oracle.dyadic_samples(h)
    i, j = np.arange(nx * ny) % nx, np.arange(nx * ny) // nx
    interior = (i > 0) & (i < nx - 1) & (j > 0) & (j < ny - 1)
    keep = interior[F[face_ids]].all(axis=1)
    face_ids, uv, vertex = face_ids[keep], uv[keep], vertex[keep]
    a_, b_, c_ = (XY[F[face_ids, k]] for k in range(3))
    p = (1 - uv.sum(axis=1))[:, None] * a_ + uv[:, :1] * b_ + uv[:, 1:] * c_
    for name, (f, lap) in POLYNOMIALS.items():
        L, expected = lattice_error(W[vertex], XY, f, lap, p)
        np.testing.assert_allclose(L, expected, rtol=0, atol=1e-11, err_msg=name)
    L, expected = lattice_error(W[vertex], XY, lambda x, y: x ** 4, lambda x, y: 12 * x * x, p)
    assert abs(L - expected).max() > 1e-3


@pytest.mark.parametrize("poly", list(POLYNOMIALS))
def test_polynomial_reproduction(poly):
    XY, F, face_ids, uv, p = lattice_interior_samples()
    W = mi_loop.limit_matrix(F, len(XY), face_ids, uv)
    f, lap = POLYNOMIALS[poly]
    L, expected = lattice_error(W, XY, f, lap, p)
    err = abs(L - expected).max(axis=1)
    np.testing.assert_allclose(L, expected, rtol=0, atol=1e-11, err_msg=f"{poly}: {worst(err, face_ids, uv)}")


def test_quartic_is_not_reproduced():
    """The same check fails for x^4 (the test can fail)."""
    XY, F, face_ids, uv, p = lattice_interior_samples()
    W = mi_loop.limit_matrix(F, len(XY), face_ids, uv)
    L, expected = lattice_error(W, XY, lambda x, y: x ** 4, lambda x, y: 12 * x * x, p)
    assert abs(L - expected).max() > 1e-3


# --------------------------------------------------------------------------
# Limit positions and normals at the control vertices
# --------------------------------------------------------------------------

def vertex_corners(F, n):
    """Return (face_ids, uv) of one incident face corner per vertex."""
    face_ids, uv = np.zeros(n, dtype=np.int64), np.zeros((n, 2))
    for f, face in reversed(list(enumerate(np.asarray(F)))):
        for v in face:
            face_ids[v], uv[v] = f, corner_uv(face, v)
    return face_ids, uv


@pytest.mark.parametrize("name", MESH_NAMES)
def test_limit_positions(name):
    mesh = meshes.MESHES[name]
    n = len(mesh.V)
    W_ref = reference(name)[1]
    face_ids, uv = vertex_corners(mesh.F, n)
    P = mi_loop.limit_positions(mesh.V, mesh.F, creases=mesh.creases)
    P_matrix = mi_loop.limit_matrix(mesh.F, n, face_ids, uv, creases=mesh.creases) @ mesh.V
    tol = 1e-10 * bbox_diagonal(mesh.V)
    np.testing.assert_allclose(P, P_matrix, rtol=0, atol=tol, err_msg=name)
    np.testing.assert_allclose(P, W_ref[:n] @ mesh.V, rtol=0, atol=tol, err_msg=name)


def reference_normals(mesh, h, W_ref):
    """Return {vertex: unit normal} at smooth, dart and boundary control vertices,
    and {vertex: unit crease tangent} at interior crease vertices.

    Evaluated on level 4, where all finite sharpness has expired, so the
    vertex kind there holds for every later step.
    """
    n = len(mesh.V)
    level = h.levels[-1]
    V_fine = h.S_total[-1] @ mesh.V
    L = W_ref @ mesh.V
    incident = [[] for _ in range(n)]
    hint = np.zeros((n, 3))  # sign only: summed normals of the level-4 limit triangles at the vertex
    for face in level.F:
        for x in face:
            if x < n:
                incident[x].append(face)
                a, b, c = face
                hint[x] += np.cross(L[b] - L[a], L[c] - L[a])
    normals, crease_tangents = {}, {}
    for v in range(n):
        kind = level.vertex_kind(v)
        if kind == "smooth":
            normals[v] = oracle.smooth_vertex_normal(V_fine, incident[v], v)
        elif kind == "dart" or (kind == "crease" and len(level.neighbours[v]) == level.n_faces_at[v] + 1):
            normals[v] = oracle.eigen_vertex_normal(V_fine, level, v, hint[v])
        elif kind == "crease":
            # Interior crease: two one-sided tangent planes, both contain the crease tangent.
            a, b = level.sharp_neighbours(v)
            crease_tangents[v] = (V_fine[b] - V_fine[a]) / np.linalg.norm(V_fine[b] - V_fine[a])
    return normals, crease_tangents


@pytest.mark.parametrize("name", MESH_NAMES)
def test_limit_normals(name):
    """Unit normals at control vertices: tangent masks (smooth), local eigenvectors (dart, boundary).

    Corners have no tangent plane and are only checked for unit length; at an
    interior crease vertex (two one-sided tangent planes) the normal must be
    orthogonal to the crease.
    At regular smooth vertices the normal also equals cross(d/du, d/dv) at the corner.
    """
    mesh = meshes.MESHES[name]
    n = len(mesh.V)
    h, W_ref, _, _, _ = reference(name)
    N = mi_loop.limit_normals(mesh.V, mesh.F, creases=mesh.creases)
    assert N.shape == (n, 3)
    np.testing.assert_allclose(np.linalg.norm(N, axis=1), 1.0, rtol=0, atol=1e-12)
    expected, crease_tangents = reference_normals(mesh, h, W_ref)
    for v in sorted(expected):
        kind = h.levels[-1].vertex_kind(v)
        np.testing.assert_allclose(N[v], expected[v], rtol=0, atol=1e-9, err_msg=f"{name}: {kind} vertex {v}")
    for v, t in crease_tangents.items():
        assert abs(np.dot(N[v], t)) < 1e-9, f"{name}: normal at crease vertex {v} not normal to the crease"

    level0 = h.levels[0]
    regular = [v for v in range(n) if level0.vertex_kind(v) == "smooth" and len(level0.neighbours[v]) == 6
               and h.levels[-1].vertex_kind(v) == "smooth"]
    if regular:
        face_ids, uv = vertex_corners(mesh.F, n)
        du, dv = (mi_loop.limit_matrix(mesh.F, n, face_ids[regular], uv[regular], creases=mesh.creases,
                                       derivative=d) @ mesh.V for d in ("u", "v"))
        normal = np.cross(du, dv)
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        np.testing.assert_allclose(N[regular], normal, rtol=0, atol=1e-9, err_msg=f"{name}: regular {regular}")


def test_dart_normal_respects_mirror_symmetry():
    """Unit octahedron, one crease edge 0-4 (darts at 0 and 4): the mesh is symmetric under
    y -> -y, so the normal at vertex 0 lies in the x-z plane; it must also equal the limit of
    cross(d/du, d/dv) approaching the vertex (its own limit_matrix at uv = 2^-30)."""
    F = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    V = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=float)
    creases = np.array([[0, 4]])
    du, dv = (mi_loop.limit_matrix(F, 6, [0], [[2.0 ** -30, 2.0 ** -30]], creases=creases, derivative=d) @ V
              for d in ("u", "v"))
    near = np.cross(du, dv)[0] / np.linalg.norm(np.cross(du, dv))
    expected = oracle.eigen_vertex_normal(V, oracle.control_level(F, 6, creases), 0, V[0])
    np.testing.assert_allclose(near, expected, rtol=0, atol=1e-8)  # the surface's own tangent plane
    N = mi_loop.limit_normals(V, F, creases=creases)
    np.testing.assert_allclose(N[0], expected, rtol=0, atol=1e-9)


@pytest.mark.parametrize("name", MESH_NAMES)
def test_closed_form_vertex_masks_equal_the_hierarchys_rows(name):
    """limit_masks (closed forms; the hierarchy for darts and semi-sharp vertices) against the rows of the
    refined hierarchy at the same corners; limit_matrix takes the closed forms only when every sample is
    at a corner."""
    from mi_loop.subdiv.masks import _masks, vertex_samples

    mesh = meshes.MESHES[name]
    n = len(mesh.V)
    fast = mi_loop.limit_masks(mesh.F, n, creases=mesh.creases).toarray()
    slow = _masks(mesh.F, n, {"creases": mesh.creases}, (None,), "test")[0].toarray()
    np.testing.assert_allclose(fast, slow, rtol=0, atol=1e-14, err_msg=name)
    face_ids, uv = vertex_samples(mesh.F, n)
    mixed = mi_loop.limit_matrix(mesh.F, n, np.r_[face_ids, 0], np.r_[uv, [[0.25, 0.25]]],
                                 creases=mesh.creases).toarray()          # one inner sample: the hierarchy
    np.testing.assert_allclose(mixed[:n], fast, rtol=0, atol=1e-14, err_msg=name)
