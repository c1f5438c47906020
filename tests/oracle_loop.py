"""Plain reference implementation of Loop subdivision for the mi_loop tests.

Deliberately simple and independent of ``mi_loop``: dictionaries and loops,
one vertex or edge at a time, so that every rule can be read off the code.
Used as the oracle for ``tests/subdiv/test_subdivision.py``,
``tests/subdiv/test_limit_exact.py`` and ``tests/subdiv/test_tiny_meshes.py``,
and checked against OpenSubdiv itself in
``tests/subdiv/test_oracle_opensubdiv.py``.

Rules: OpenSubdiv 3.6's Sdc crease model for the Loop scheme
-------------------------------------------------------------
Read off ``sdc/crease.cpp``, ``sdc/scheme.h``, ``sdc/loopScheme.h``,
``far/topologyRefinerFactory.cpp`` (tags), ``vtr/refinement.cpp`` (child
sharpness and rules) and ``far/primvarRefiner.h`` (which rules the masks get).

- Sharpness: an edge or vertex sharpness s <= 0 is smooth, s >= 10
  (``SHARPNESS_INFINITE``) or inf is infinitely sharp, anything between is
  semi-sharp. Boundary edges are always infinitely sharp. Under
  ``boundary='edge_and_corner'`` a vertex with one face and two edges gets
  infinite vertex sharpness; under ``'none'`` the faces around a boundary
  vertex with a boundary edge not explicitly infinitely sharp are holes
  (:func:`hole_faces`; they are still refined, as OpenSubdiv does).
- Child sharpness: vertex s -> s - 1 (0 once s <= 1; inf stays inf). The
  child of edge v-w next to v: ``'uniform'`` s - 1 likewise; ``'chaikin'``
  (3/4 s + 1/4 mean of the *other* semi-sharp edges at v) - 1, infinite
  and smooth edges left out of the mean, plain s - 1 when s is the only
  semi-sharp edge at v or v has fewer than 2 edges.
- Vertex rule (Crease::DetermineVertexVertexRule): vertex sharpness > 0 ->
  corner; else by the number of incident edges with sharpness > 0:
  0 smooth, 1 dart, 2 crease, 3 or more corner.
- Vertex point: parent rule smooth or dart -> (1 - k beta) v + beta sum(p).
  Else the parent mask (crease 3/4 v + 1/8 each sharp neighbour, corner v);
  if the child rule differs, a * parent + (1 - a) * child mask, with
  a = min(1, mean of the transitioning sharpnesses) (Crease::
  ComputeFractionalWeightAtVertex; uniform: the edges with 0 < s <= 1,
  chaikin: the edges whose child is smooth; plus the vertex sharpness if it
  decays to 0).
- Edge point: s <= 0 -> 3/8 (a + b) + 1/8 (c + d). Else, if both child
  edges are still sharp (child rule crease) -> midpoint; otherwise
  s * midpoint + (1 - s) * smooth, with s the parent sharpness *unclamped*
  (Far passes the child rule, so the clamp in ComputeEdgeVertexMask's
  unknown-rule branch is skipped: under chaikin an edge with 1 < s < 2 whose
  child is smooth gets a weight above 1).

beta(k) = (5/8 - (3/8 + cos(2 pi/k)/4)^2) / k.

Limit points at dyadic parameters come from iterated subdivision until no
semi-sharp tag is left, then the limit mask at the vertex by its rule:
smooth chi = 1/(3/(8 beta) + k) per neighbour, crease 1/6, 2/3, 1/6 (also a
one-face vertex under 'edge_only' or 'none'), corner 1 (also an interior
vertex of infinite sharpness). For a dart the smooth mask is not invariant
under the rules above (the crease edge point is a midpoint), so the oracle
takes the mask from the dominant left eigenvector of the local one-ring
subdivision matrix, which is exact by construction (OpenSubdiv uses the
smooth mask there).

Every vertex of every level carries ``label[v] = {control face: (u, v)}``:
the parameter of the vertex in each control face whose closed domain
contains it, with (1-u-v) a + u b + v c for the control face (a, b, c).
Fine face ``4 f + i`` (i = 0..3) of a step descends from coarse face f.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

INF = math.inf
SHARPNESS_INFINITE = 10.0       # Sdc::Crease::SHARPNESS_INFINITE
BOUNDARY_RULES = ("edge_and_corner", "edge_only", "none")
CREASE_METHODS = ("uniform", "chaikin")


def loop_beta(k: int) -> float:
    """Return Loop's original vertex weight beta(k) for valence k."""
    return (5.0 / 8.0 - (3.0 / 8.0 + math.cos(2.0 * math.pi / k) / 4.0) ** 2) / k


def edge_key(a: int, b: int) -> tuple[int, int]:
    """Return the undirected edge (a, b) as a sorted pair."""
    return (a, b) if a < b else (b, a)


# --------------------------------------------------------------------------
# Sharpness values and rules (Sdc::Crease; no topology)
# --------------------------------------------------------------------------

def tag_sharpness(s) -> float:
    """Return a user sharpness as stored: 0.0 if s <= 0, inf if s >= 10, else s."""
    s = float(s)
    if math.isnan(s):
        raise ValueError("oracle: sharpness is NaN")
    if s >= SHARPNESS_INFINITE:
        return INF
    return s if s > 0.0 else 0.0


def _tag_list(items, sharpness, n_items: int) -> list:
    """Return [(item, stored sharpness)] of a (items, sharpness) pair; sharpness may be a scalar."""
    s = np.broadcast_to(np.asarray(sharpness, dtype=float), (n_items,))
    return [(item, tag_sharpness(x)) for item, x in zip(items, s)]


def parse_creases(creases) -> dict[tuple[int, int], float]:
    """Return {sorted edge: stored sharpness} for the mi_loop ``creases`` argument.

    ``creases`` is None, a (c, 2) int array of infinitely sharp edges, or a
    tuple ``(E (c, 2) int, sharpness (c,) float or scalar)``.
    """
    if creases is None:
        return {}
    if isinstance(creases, tuple):
        E, s = creases
        E = np.asarray(E).reshape(-1, 2)
        return {edge_key(int(a), int(b)): x for (a, b), x in _tag_list(E, s, len(E))}
    return {edge_key(int(a), int(b)): INF for a, b in np.asarray(creases).reshape(-1, 2)}


def parse_corners(corners) -> dict[int, float]:
    """Return {vertex: stored sharpness} for ``corners``.

    ``corners`` is None, an int array of infinitely sharp vertices, or a
    tuple ``(vertex_ids (c,) int, sharpness (c,) float or scalar)``.
    """
    if corners is None:
        return {}
    if isinstance(corners, tuple):
        ids, s = corners
        ids = np.asarray(ids).reshape(-1)
        return {int(v): x for v, x in _tag_list(ids, s, len(ids))}
    return {int(v): INF for v in np.asarray(corners).reshape(-1)}


def decrement_sharpness(s: float) -> float:
    """Return the child of a vertex sharpness, or of an edge sharpness under 'uniform'."""
    if s <= 0.0:
        return 0.0
    if s == INF:
        return INF
    return s - 1.0 if s > 1.0 else 0.0


def child_edge_sharpness_at_vertex(s: float, around: list, crease_method: str) -> float:
    """Return the sharpness of the child, next to vertex v, of an edge of sharpness s.

    ``around`` lists the sharpness of every edge at v (s included); this is
    Crease::SubdivideEdgeSharpnessAtVertex.
    """
    if crease_method == "uniform" or len(around) < 2:
        return decrement_sharpness(s)
    if s <= 0.0:
        return 0.0
    if s == INF:
        return INF
    semi = [x for x in around if 0.0 < x < INF]
    if len(semi) > 1:
        others = (sum(semi) - s) / (len(semi) - 1)
        s = 0.75 * s + 0.25 * others
    s -= 1.0
    return s if s > 0.0 else 0.0


def vertex_rule(vertex_sharpness: float, n_sharp_edges: int) -> str:
    """Return 'smooth', 'dart', 'crease' or 'corner' (Crease::DetermineVertexVertexRule)."""
    if vertex_sharpness > 0.0 or n_sharp_edges > 2:
        return "corner"
    return ("smooth", "dart", "crease")[n_sharp_edges]


def fractional_weight(vertex_s: float, child_vertex_s: float, edge_s: list, child_edge_s: list,
                      crease_method: str) -> float:
    """Return the weight of the parent mask when a vertex changes rule.

    Crease::ComputeFractionalWeightAtVertex: the mean of the sharpness values
    that decay to 0 in this step, clamped to 1.
    """
    decaying = []
    if vertex_s > 0.0 and child_vertex_s <= 0.0:
        decaying.append(vertex_s)
    for s, c in zip(edge_s, child_edge_s):
        if crease_method == "uniform" and 0.0 < s <= 1.0:
            decaying.append(s)
        if crease_method == "chaikin" and s > 0.0 and c <= 0.0:
            decaying.append(s)
    if not decaying:
        return 0.0
    return min(1.0, sum(decaying) / len(decaying))


def levels_to_expire(creases=None, corners=None) -> int:
    """Return how many steps remove every semi-sharp tag: the ceiling of the largest finite sharpness.

    Chaikin never makes a sharpness larger than the largest at its vertex, so
    this bounds both crease methods.
    """
    finite = [s for s in list(parse_creases(creases).values()) + list(parse_corners(corners).values())
              if 0.0 < s < INF]
    return int(math.ceil(max(finite))) if finite else 0


def _check_options(boundary: str, crease_method: str) -> None:
    if boundary not in BOUNDARY_RULES:
        raise ValueError(f"oracle: boundary must be one of {BOUNDARY_RULES}, got {boundary!r}")
    if crease_method not in CREASE_METHODS:
        raise ValueError(f"oracle: crease_method must be one of {CREASE_METHODS}, got {crease_method!r}")


@dataclass
class Level:
    """One level of the subdivision hierarchy.

    F : list of (a, b, c) vertex triples.
    n : number of vertices.
    sharpness : {sorted edge: sharpness} of sharp interior edges (> 0 only;
        boundary edges are infinitely sharp without an entry).
    label : per vertex {control face: (u, v)}.
    vertex_sharpness : {vertex: sharpness} (> 0 only).
    crease_method : 'uniform' or 'chaikin'.
    """

    F: list
    n: int
    sharpness: dict
    label: list
    vertex_sharpness: dict = field(default_factory=dict)
    crease_method: str = "uniform"
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

    def edge_sharpness(self, a: int, b: int) -> float:
        """Return the sharpness of edge a-b (inf on the boundary)."""
        e = edge_key(a, b)
        return INF if len(self.opposite[e]) == 1 else self.sharpness.get(e, 0.0)

    def is_sharp(self, a: int, b: int) -> bool:
        return self.edge_sharpness(a, b) > 0.0

    def sharp_neighbours(self, v: int) -> list:
        return sorted(w for w in self.neighbours[v] if self.is_sharp(v, w))

    def vertex_kind(self, v: int) -> str:
        """Return the rule of v: 'smooth', 'dart', 'crease' or 'corner'."""
        return vertex_rule(self.vertex_sharpness.get(v, 0.0), len(self.sharp_neighbours(v)))

    def child_edge_sharpness(self, v: int, w: int) -> float:
        """Return the sharpness of the child of edge v-w that ends at v."""
        around = [self.edge_sharpness(v, x) for x in self.neighbours[v]]
        return child_edge_sharpness_at_vertex(self.edge_sharpness(v, w), around, self.crease_method)


# --------------------------------------------------------------------------
# One step
# --------------------------------------------------------------------------

def _rule_mask(level: Level, v: int, rule: str, sharp: list) -> dict:
    """Return the refinement mask of v for ``rule``; ``sharp`` holds the crease neighbours."""
    if rule == "corner":
        return {v: 1.0}
    if rule == "crease":
        a, b = sharp
        return {v: 0.75, a: 0.125, b: 0.125}
    k = len(level.neighbours[v])
    beta = loop_beta(k)
    weights = {v: 1.0 - k * beta}
    for w in level.neighbours[v]:
        weights[w] = beta
    return weights


def _blend(p: dict, a: float, q: dict) -> dict:
    """Return a * p + (1 - a) * q for masks {vertex: weight}."""
    out = {w: a * x for w, x in p.items()}
    for w, x in q.items():
        out[w] = out.get(w, 0.0) + (1.0 - a) * x
    return out


def vertex_point(level: Level, v: int) -> dict:
    """Return the weights {old vertex: w} of the new position of old vertex v."""
    rule = level.vertex_kind(v)
    if rule in ("smooth", "dart"):
        return _rule_mask(level, v, "smooth", [])
    parent = _rule_mask(level, v, rule, level.sharp_neighbours(v))
    ring = sorted(level.neighbours[v])
    edge_s = [level.edge_sharpness(v, w) for w in ring]
    child_s = [level.child_edge_sharpness(v, w) for w in ring]
    vertex_s = level.vertex_sharpness.get(v, 0.0)
    child_vertex_s = decrement_sharpness(vertex_s)
    child_sharp = [w for w, s in zip(ring, child_s) if s > 0.0]
    child_rule = vertex_rule(child_vertex_s, len(child_sharp))
    if child_rule == rule:
        return parent
    child = _rule_mask(level, v, child_rule, child_sharp)
    a = fractional_weight(vertex_s, child_vertex_s, edge_s, child_s, level.crease_method)
    return _blend(parent, a, child)


def edge_point(level: Level, a: int, b: int) -> dict:
    """Return the weights {old vertex: w} of the new vertex of edge a-b."""
    s = level.edge_sharpness(a, b)
    midpoint = {a: 0.5, b: 0.5}
    if s > 0.0 and level.child_edge_sharpness(a, b) > 0.0 and level.child_edge_sharpness(b, a) > 0.0:
        return midpoint     # the child vertex is a crease
    c, d = level.opposite[edge_key(a, b)]
    smooth = {a: 0.375, b: 0.375, c: 0.125, d: 0.125}
    if s <= 0.0:
        return smooth
    return _blend(midpoint, s, smooth)     # s may exceed 1 under chaikin (see the module notes)


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
    for (a, b), m in edge_vertex.items():
        if len(level.opposite[(a, b)]) == 2 and level.edge_sharpness(a, b) > 0.0:
            for x in (a, b):
                s = level.child_edge_sharpness(x, b if x == a else a)
                if s > 0.0:
                    sharpness_fine[edge_key(x, m)] = s
    vertex_sharpness_fine = {v: decrement_sharpness(s) for v, s in level.vertex_sharpness.items()
                             if decrement_sharpness(s) > 0.0}

    label = list(level.label) + [None] * len(edge_vertex)
    for (a, b), m in edge_vertex.items():
        common = set(level.label[a]) & set(level.label[b])
        if not common:
            raise RuntimeError(f"oracle: edge {a}-{b} has no common control face")
        label[m] = {f: ((level.label[a][f][0] + level.label[b][f][0]) / 2,
                        (level.label[a][f][1] + level.label[b][f][1]) / 2) for f in common}

    fine = Level(F=F_fine, n=n_fine, sharpness=sharpness_fine, label=label,
                 vertex_sharpness=vertex_sharpness_fine, crease_method=level.crease_method)
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


def control_level(F, n_vertices: int, creases=None, *, corners=None, boundary: str = "edge_and_corner",
                  crease_method: str = "uniform") -> Level:
    """Return level 0 with parameter labels, sharpness tags and the boundary rule applied.

    ``creases`` (edges, sharpness) and ``corners`` (vertex ids, sharpness)
    are in the formats of :func:`parse_creases` and :func:`parse_corners`.
    """
    _check_options(boundary, crease_method)
    F = [tuple(int(x) for x in f) for f in np.asarray(F)]
    label = [{} for _ in range(n_vertices)]
    for f, (a, b, c) in enumerate(F):
        label[a][f] = (0.0, 0.0)
        label[b][f] = (1.0, 0.0)
        label[c][f] = (0.0, 1.0)
    sharpness = {e: s for e, s in parse_creases(creases).items() if s > 0.0}
    vertex_sharpness = {v: s for v, s in parse_corners(corners).items() if s > 0.0}
    level = Level(F=F, n=n_vertices, sharpness=sharpness, label=label,
                  vertex_sharpness=vertex_sharpness, crease_method=crease_method)
    level.build_topology()
    for e in sharpness:
        if e not in level.opposite:
            raise ValueError(f"oracle: crease edge {e} is not an edge of the mesh")
    for v in vertex_sharpness:
        if not 0 <= v < n_vertices:
            raise ValueError(f"oracle: corner vertex {v} is not in [0, {n_vertices})")
    if boundary == "edge_and_corner":
        for v in range(n_vertices):
            if level.n_faces_at[v] == 1 and len(level.neighbours[v]) == 2:
                level.vertex_sharpness[v] = INF
    return level


def hole_faces(F, n_vertices: int, creases=None, boundary: str = "none") -> np.ndarray:
    """Return the sorted control faces that OpenSubdiv makes holes (only under boundary='none').

    A face is a hole if one of its vertices has a boundary edge whose given
    sharpness is not infinite (prepareComponentTagsAndSharpness).
    """
    _check_options(boundary, "uniform")
    if boundary != "none":
        return np.zeros(0, dtype=np.int64)
    level = control_level(F, n_vertices)
    given = parse_creases(creases)
    holes = set()
    for v in range(n_vertices):
        if any(len(level.opposite[edge_key(v, w)]) == 1 and given.get(edge_key(v, w), 0.0) < INF
               for w in level.neighbours[v]):
            holes |= {f for f in level.label[v]}
    return np.array(sorted(holes), dtype=np.int64)


def one_step_matrix(F, n_vertices: int, creases=None, *, corners=None, boundary: str = "edge_and_corner",
                    crease_method: str = "uniform"):
    """Return (S CSR (n_fine, n), F_fine list, edge_vertex dict) of one step."""
    level = control_level(F, n_vertices, creases, corners=corners, boundary=boundary, crease_method=crease_method)
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
    """Return the limit mask {vertex: weight} at v (no semi-sharp tag left around v)."""
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
    holes : sorted control faces that are holes (boundary='none' only).
    """

    levels: list
    S_total: list
    holes: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))


def subdivide(F, n_vertices: int, creases=None, n_levels: int = 4, *, corners=None,
              boundary: str = "edge_and_corner", crease_method: str = "uniform") -> Hierarchy:
    """Return the hierarchy of ``n_levels`` Loop steps of the control mesh."""
    level = control_level(F, n_vertices, creases, corners=corners, boundary=boundary, crease_method=crease_method)
    levels, S_total = [level], [np.eye(n_vertices)]
    for _ in range(n_levels):
        level, rows, _ = subdivide_once(level)
        S = rows_to_csr(rows, level.n, levels[-1].n)
        levels.append(level)
        S_total.append(np.asarray(S @ S_total[-1]))
    return Hierarchy(levels=levels, S_total=S_total, holes=hole_faces(F, n_vertices, creases, boundary))


def limit_rows(h: Hierarchy) -> np.ndarray:
    """Return (n_L, n_0) exact limit rows at the vertices of the finest level."""
    level, S = h.levels[-1], h.S_total[-1]
    finite = [s for s in list(level.sharpness.values()) + list(level.vertex_sharpness.values()) if 0.0 < s < INF]
    if finite:
        raise ValueError(f"oracle: finite sharpness {finite[0]} left at the finest level; subdivide more")
    W = np.zeros_like(S)
    for v in range(level.n):
        for w, m in limit_mask(level, v).items():
            W[v] += m * S[w]
    return W


def dyadic_samples(h: Hierarchy, include_holes: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return (face_ids (k,), uv (k, 2), vertex (k,)) for every (vertex, control face) label.

    Labels in hole faces (``h.holes``) are left out unless ``include_holes``.
    """
    holes = set(int(f) for f in h.holes) if not include_holes else set()
    face_ids, uv, vertex = [], [], []
    for v, lab in enumerate(h.levels[-1].label):
        for f in sorted(lab):
            if f in holes:
                continue
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
    level0 = h.levels[0]
    if any(0.0 < s < INF for s in list(level0.sharpness.values()) + list(level0.vertex_sharpness.values())):
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
