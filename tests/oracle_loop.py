"""Plain reference implementation of Loop subdivision for the mi_loop tests.

Deliberately simple and independent of ``mi_loop``: dictionaries and loops,
one vertex or edge at a time, so that every rule can be read off the code.
Used as the oracle for ``tests/test_subdivision.py`` and
``tests/test_limit_exact.py``.

Rules (Loop's original weights, Hoppe-style sharp edges)
--------------------------------------------------------
beta(k) = (5/8 - (3/8 + cos(2 pi/k)/4)^2) / k.
An edge is sharp at a step if it is a boundary edge or a crease edge with
sharpness s > 0; the two children of a crease edge get sharpness s - 1.

- Edge point: sharp edge -> midpoint; otherwise 3/8 (a + b) + 1/8 (c + d).
- Vertex point, by the number of sharp incident edges: 0 or 1 -> smooth
  (1 - k beta) v + beta sum(neighbours); 2 -> 3/4 v + 1/8 each sharp
  neighbour; 3 or more, or a vertex with a single incident face -> corner.

Limit points at dyadic parameters come from iterated subdivision followed by
the limit mask at the vertex: smooth chi = 1/(3/(8 beta) + k) per neighbour,
crease 1/6, 2/3, 1/6, corner 1. For a dart (exactly one sharp edge) the smooth
mask is not invariant under the rules above (the crease edge point is a
midpoint), so the oracle takes the mask from the dominant left eigenvector of
the local one-ring subdivision matrix, which is exact by construction.

Every vertex of every level carries ``label[v] = {control face: (u, v)}``:
the parameter of the vertex in each control face whose closed domain
contains it, with (1-u-v) a + u b + v c for the control face (a, b, c).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

INF = math.inf


def loop_beta(k: int) -> float:
    """Return Loop's original vertex weight beta(k) for valence k."""
    return (5.0 / 8.0 - (3.0 / 8.0 + math.cos(2.0 * math.pi / k) / 4.0) ** 2) / k


def edge_key(a: int, b: int) -> tuple[int, int]:
    """Return the undirected edge (a, b) as a sorted pair."""
    return (a, b) if a < b else (b, a)


def parse_creases(creases) -> dict[tuple[int, int], float]:
    """Return {sorted edge: sharpness} for the mi_loop ``creases`` argument."""
    if creases is None:
        return {}
    if isinstance(creases, tuple):
        E, s = creases
        return {edge_key(int(a), int(b)): float(x) for (a, b), x in zip(np.asarray(E), np.asarray(s))}
    return {edge_key(int(a), int(b)): INF for a, b in np.asarray(creases)}


@dataclass
class Level:
    """One level of the subdivision hierarchy.

    F : list of (a, b, c) vertex triples.
    n : number of vertices.
    sharpness : {sorted edge: remaining sharpness} of crease edges (> 0 only).
    label : per vertex {control face: (u, v)}.
    """

    F: list
    n: int
    sharpness: dict
    label: list
    # Topology, filled by ``build_topology``.
    opposite: dict = field(default_factory=dict)   # edge -> list of opposite vertices
    neighbours: list = field(default_factory=list)  # vertex -> set of neighbours
    n_faces_at: list = field(default_factory=list)  # vertex -> number of incident faces

    def build_topology(self) -> None:
        self.opposite = {}
        self.neighbours = [set() for _ in range(self.n)]
        self.n_faces_at = [0] * self.n
        for a, b, c in self.F:
            for x, y, z in ((a, b, c), (b, c, a), (c, a, b)):
                self.opposite.setdefault(edge_key(x, y), []).append(z)
                self.neighbours[x].add(y)
                self.neighbours[y].add(x)
                self.n_faces_at[x] += 1

    def is_sharp(self, a: int, b: int) -> bool:
        e = edge_key(a, b)
        return len(self.opposite[e]) == 1 or self.sharpness.get(e, 0.0) > 0.0

    def sharp_neighbours(self, v: int) -> list:
        return sorted(w for w in self.neighbours[v] if self.is_sharp(v, w))

    def vertex_kind(self, v: int) -> str:
        """Return 'smooth', 'dart', 'crease' or 'corner'."""
        n_sharp = len(self.sharp_neighbours(v))
        if n_sharp >= 3 or self.n_faces_at[v] == 1:
            return "corner"
        return ("smooth", "dart", "crease")[n_sharp]


# --------------------------------------------------------------------------
# One step
# --------------------------------------------------------------------------

def vertex_point(level: Level, v: int) -> dict:
    """Return the weights {old vertex: w} of the new position of old vertex v."""
    kind = level.vertex_kind(v)
    if kind == "corner":
        return {v: 1.0}
    if kind == "crease":
        a, b = level.sharp_neighbours(v)
        return {v: 0.75, a: 0.125, b: 0.125}
    k = len(level.neighbours[v])
    beta = loop_beta(k)
    weights = {v: 1.0 - k * beta}
    for w in level.neighbours[v]:
        weights[w] = beta
    return weights


def edge_point(level: Level, a: int, b: int) -> dict:
    """Return the weights {old vertex: w} of the new vertex of edge a-b."""
    if level.is_sharp(a, b):
        return {a: 0.5, b: 0.5}
    c, d = level.opposite[edge_key(a, b)]
    return {a: 0.375, b: 0.375, c: 0.125, d: 0.125}


def subdivide_once(level: Level) -> tuple[Level, dict, dict]:
    """Apply one Loop step.

    Returns
    -------
    fine : Level
    rows : {fine vertex: {coarse vertex: weight}}
    edge_vertex : {sorted coarse edge: fine vertex index}
    """
    rows = {v: vertex_point(level, v) for v in range(level.n)}
    edge_vertex = {}
    for a, b, c in level.F:
        for x, y in ((a, b), (b, c), (c, a)):
            e = edge_key(x, y)
            if e not in edge_vertex:
                edge_vertex[e] = level.n + len(edge_vertex)
                rows[edge_vertex[e]] = edge_point(level, x, y)
    n_fine = level.n + len(edge_vertex)

    F_fine = []
    for a, b, c in level.F:
        ab = edge_vertex[edge_key(a, b)]
        bc = edge_vertex[edge_key(b, c)]
        ca = edge_vertex[edge_key(c, a)]
        F_fine += [(a, ab, ca), (ab, b, bc), (ca, bc, c), (bc, ca, ab)]

    sharpness_fine = {}
    for (a, b), s in level.sharpness.items():
        if s > 0.0 and (a, b) in edge_vertex:
            m = edge_vertex[(a, b)]
            sharpness_fine[edge_key(a, m)] = s - 1.0
            sharpness_fine[edge_key(m, b)] = s - 1.0

    label = list(level.label) + [None] * len(edge_vertex)
    for (a, b), m in edge_vertex.items():
        common = set(level.label[a]) & set(level.label[b])
        if not common:
            raise RuntimeError(f"oracle: edge {a}-{b} has no common control face")
        label[m] = {f: ((level.label[a][f][0] + level.label[b][f][0]) / 2,
                        (level.label[a][f][1] + level.label[b][f][1]) / 2) for f in common}

    fine = Level(F=F_fine, n=n_fine, sharpness=sharpness_fine, label=label)
    fine.build_topology()
    return fine, rows, edge_vertex


def rows_to_csr(rows: dict, n_rows: int, n_cols: int) -> sp.csr_matrix:
    """Return the CSR matrix of {row: {col: weight}}."""
    I, J, W = [], [], []
    for i in range(n_rows):
        for j, w in rows[i].items():
            I.append(i)
            J.append(j)
            W.append(w)
    return sp.csr_matrix((W, (I, J)), shape=(n_rows, n_cols))


def control_level(F, n_vertices: int, creases=None) -> Level:
    """Return level 0 with parameter labels at the control vertices."""
    F = [tuple(int(x) for x in f) for f in np.asarray(F)]
    label = [{} for _ in range(n_vertices)]
    for f, (a, b, c) in enumerate(F):
        label[a][f] = (0.0, 0.0)
        label[b][f] = (1.0, 0.0)
        label[c][f] = (0.0, 1.0)
    level = Level(F=F, n=n_vertices, sharpness=parse_creases(creases), label=label)
    level.build_topology()
    return level


def one_step_matrix(F, n_vertices: int, creases=None):
    """Return (S CSR (n_fine, n), F_fine list, edge_vertex dict) of one step."""
    level = control_level(F, n_vertices, creases)
    fine, rows, edge_vertex = subdivide_once(level)
    return rows_to_csr(rows, fine.n, level.n), fine.F, edge_vertex


# --------------------------------------------------------------------------
# Limit masks and exact limit points
# --------------------------------------------------------------------------

def local_subdivision_matrix(level: Level, v: int) -> tuple[np.ndarray, list]:
    """Return the one-ring subdivision matrix at v and the ring order [v, p...].

    Row 0 is the new position of v, row i the new vertex of edge v-p_i, both
    in terms of the old one-ring (the one-ring of Loop's rules is closed).
    """
    ring = [v] + sorted(level.neighbours[v])
    index = {w: i for i, w in enumerate(ring)}
    M = np.zeros((len(ring), len(ring)))
    for j, w in vertex_point(level, v).items():
        M[0, index[j]] += w
    for i, p in enumerate(ring[1:], start=1):
        for j, w in edge_point(level, v, p).items():
            M[i, index[j]] += w
    return M, ring


def eigen_limit_mask(level: Level, v: int) -> dict:
    """Return the limit mask at v as the left eigenvector of eigenvalue 1."""
    M, ring = local_subdivision_matrix(level, v)
    lam, L = np.linalg.eig(M.T)
    i = int(np.argmin(abs(lam - 1.0)))
    if abs(lam[i] - 1.0) > 1e-12 or np.sort(abs(lam))[-2] > 1.0 - 1e-6:
        raise RuntimeError(f"oracle: local matrix at {v} has no simple eigenvalue 1: {lam}")
    l = np.real(L[:, i])
    l = l / l.sum()
    return {w: float(x) for w, x in zip(ring, l)}


def limit_mask(level: Level, v: int) -> dict:
    """Return the limit mask {vertex: weight} at v (no finite sharpness left)."""
    kind = level.vertex_kind(v)
    if kind == "corner":
        return {v: 1.0}
    if kind == "crease":
        a, b = level.sharp_neighbours(v)
        return {v: 2.0 / 3.0, a: 1.0 / 6.0, b: 1.0 / 6.0}
    if kind == "dart":
        return eigen_limit_mask(level, v)
    k = len(level.neighbours[v])
    chi = 1.0 / (3.0 / (8.0 * loop_beta(k)) + k)
    mask = {v: 1.0 - k * chi}
    for w in level.neighbours[v]:
        mask[w] = chi
    return mask


@dataclass
class Hierarchy:
    """Iterated subdivision of a control mesh.

    levels : list of Level, levels[0] is the control mesh.
    S_total : list of dense (n_l, n_0) arrays, control -> level l.
    """

    levels: list
    S_total: list


def subdivide(F, n_vertices: int, creases=None, n_levels: int = 4) -> Hierarchy:
    """Return the hierarchy of ``n_levels`` Loop steps of the control mesh."""
    level = control_level(F, n_vertices, creases)
    levels, S_total = [level], [np.eye(n_vertices)]
    for _ in range(n_levels):
        level, rows, _ = subdivide_once(level)
        S = rows_to_csr(rows, level.n, levels[-1].n)
        levels.append(level)
        S_total.append(np.asarray(S @ S_total[-1]))
    return Hierarchy(levels=levels, S_total=S_total)


def limit_rows(h: Hierarchy) -> np.ndarray:
    """Return (n_L, n_0) exact limit rows at the vertices of the finest level."""
    level, S = h.levels[-1], h.S_total[-1]
    finite = [s for s in level.sharpness.values() if 0.0 < s < INF]
    if finite:
        raise ValueError(f"oracle: finite sharpness {finite[0]} left at the finest level; subdivide more")
    W = np.zeros_like(S)
    for v in range(level.n):
        for w, m in limit_mask(level, v).items():
            W[v] += m * S[w]
    return W


def dyadic_samples(h: Hierarchy) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return (face_ids (k,), uv (k, 2), vertex (k,)) for every (vertex, control face) label."""
    face_ids, uv, vertex = [], [], []
    for v, lab in enumerate(h.levels[-1].label):
        for f in sorted(lab):
            face_ids.append(f)
            uv.append(lab[f])
            vertex.append(v)
    return np.array(face_ids), np.array(uv, dtype=float), np.array(vertex)


def ordered_ring(F, v: int) -> list:
    """Return the neighbours of interior vertex v in face order (v, p_i, p_i+1)."""
    nxt = {}
    for f in np.asarray(F):
        for i in range(3):
            if f[i] == v:
                nxt[int(f[(i + 1) % 3])] = int(f[(i + 2) % 3])
    start = min(nxt)
    ring = [start]
    while nxt[ring[-1]] != start:
        ring.append(nxt[ring[-1]])
    if len(ring) != len(nxt):
        raise ValueError(f"oracle: vertex {v} is not an interior manifold vertex")
    return ring


def smooth_vertex_normal(V, F, v: int) -> np.ndarray:
    """Return the unit limit normal at a smooth interior vertex from tangent masks.

    t1 = sum cos(2 pi i/k) p_i, t2 = sum sin(2 pi i/k) p_i are left
    eigenvectors of the one-ring matrix for the subdominant eigenvalue
    3/8 + cos(2 pi/k)/4; for a ring in face order cross(t1, t2) points along
    the face normals.
    """
    ring = ordered_ring(F, v)
    k = len(ring)
    t1 = sum(math.cos(2 * math.pi * i / k) * V[p] for i, p in enumerate(ring))
    t2 = sum(math.sin(2 * math.pi * i / k) * V[p] for i, p in enumerate(ring))
    n = np.cross(t1, t2)
    return n / np.linalg.norm(n)


def eigen_vertex_normal(V, level: Level, v: int, hint: np.ndarray) -> np.ndarray:
    """Return the unit limit normal at a non-corner vertex from the local eigenvectors.

    The tangent plane is spanned by l_2 . P and l_3 . P, the left
    eigenvectors of the two largest eigenvalues below 1 of the one-ring
    matrix (these two must be separated from the rest). ``hint`` (3,) only
    picks the sign: the result has a positive dot product with it.
    """
    M, ring = local_subdivision_matrix(level, v)
    lam, L = np.linalg.eig(M.T)
    order = np.argsort(-abs(lam))
    lam, L = lam[order], L[:, order]
    if abs(lam[0] - 1) > 1e-12 or abs(lam[1]) > 1 - 1e-6 or abs(lam[2]) - abs(lam[3]) < 1e-6:
        raise RuntimeError(f"oracle: no isolated subdominant pair at vertex {v}: {lam}")
    P = np.asarray(V)[ring]
    n = np.cross(np.real(L[:, 1]) @ P, np.real(L[:, 2]) @ P)
    n = n / np.linalg.norm(n)
    return n if np.dot(n, hint) > 0 else -n


# --------------------------------------------------------------------------
# Exact parametric derivatives on polynomial sub-patches
# --------------------------------------------------------------------------

def _inside(i: int, j: int, corner: tuple, up: bool, side: int) -> bool:
    """Whether grid point (i, j) lies in the closed sub-triangle at ``corner`` (grid units)."""
    a, b = i - corner[0], j - corner[1]
    if up:      # (c0, c1), (c0 + side, c1), (c0, c1 + side)
        return a >= 0 and b >= 0 and a + b <= side
    return a <= 0 and b <= 0 and a + b >= -side   # (c0, c1) is the right-angle corner of a down triangle


def polynomial_derivatives(h: Hierarchy, V, patch_level: int):
    """Return exact d/du, d/dv of the limit at grid points inside regular sub-patches.

    After ``patch_level >= 1`` Loop steps of a mesh without finite sharpness,
    a sub-triangle of that level whose three corners are not control vertices
    has three regular corners (new vertices are regular), so the limit over it
    is one quartic polynomial in ``(u, v)`` (a box spline). On the dyadic grid
    of the finest level (spacing ``d = 2^-L``), the five-point stencil
    ``(f(x - 2d) - 8 f(x - d) + 8 f(x + d) - f(x + 2d)) / (12 d)`` is exact for
    quartics, so it gives the exact derivative wherever the stencil fits in
    one such sub-triangle (closed).

    Parameters
    ----------
    h : Hierarchy
        From :func:`subdivide`, with ``len(h.levels) - 1 > patch_level``.
    V : (n, 3) float array
        Control points.
    patch_level : int
        Level of the polynomial sub-triangles (1 or more).

    Returns
    -------
    face_ids : (k,) int array
    uv : (k, 2) float array
    du, dv : (k, 3) float arrays
        Exact derivatives; ``du`` is NaN where only the v-stencil fits, and
        ``dv`` where only the u-stencil fits.
    """
    L = len(h.levels) - 1
    if patch_level < 1 or patch_level > L - 2:
        raise ValueError(f"oracle: patch_level must be in [1, L - 2 = {L - 2}], got {patch_level}")
    if any(0.0 < s < INF for s in h.levels[0].sharpness.values()):
        raise ValueError("oracle: finite sharpness: sub-patches are polynomial only once it has expired")
    R, side = 2 ** L, 2 ** (L - patch_level)
    limit = limit_rows(h) @ np.asarray(V, dtype=float)
    vertex_at = {}   # (control face, i, j) -> level-L vertex at (u, v) = (i, j) / R
    for v, lab in enumerate(h.levels[-1].label):
        for f, (u, w) in lab.items():
            vertex_at[(f, round(u * R), round(w * R))] = v
    control_corners = {(0, 0), (R, 0), (0, R)}
    patches = []     # (corner, up) of the sub-triangles without a control vertex
    for ci in range(0, R, side):
        for cj in range(0, R - ci, side):
            if not control_corners & {(ci, cj), (ci + side, cj), (ci, cj + side)}:
                patches.append(((ci, cj), True))
            if ci + cj + 2 * side <= R:
                patches.append(((ci + side, cj + side), False))
    out = []
    for f in range(len(h.levels[0].F)):
        for i in range(R + 1):
            for j in range(R + 1 - i):
                d = [np.full(3, np.nan), np.full(3, np.nan)]
                for axis, (di, dj) in enumerate(((1, 0), (0, 1))):
                    stencil = [(i + k * di, j + k * dj) for k in (-2, -1, 0, 1, 2)]
                    if any(all(_inside(a, b, c, up, side) for a, b in stencil) for c, up in patches):
                        y = [limit[vertex_at[(f, a, b)]] for a, b in stencil]
                        d[axis] = (y[0] - 8 * y[1] + 8 * y[3] - y[4]) * R / 12.0
                if np.isfinite(d[0]).all() or np.isfinite(d[1]).all():
                    out.append((f, i / R, j / R, d[0], d[1]))
    face_ids = np.array([o[0] for o in out])
    uv = np.array([(o[1], o[2]) for o in out])
    return face_ids, uv, np.array([o[3] for o in out]), np.array([o[4] for o in out])
