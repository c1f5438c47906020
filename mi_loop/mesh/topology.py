"""Triangle-mesh topology in NumPy: edges, half-edge look-ups, validation, creases.

Everything here is connectivity only; no vertex positions except in
:func:`validate_mesh`, which also checks coordinates.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np


def _fail(func: str, message: str):
    where = f"{func}()" if func.isidentifier() or "." in func and func.replace(".", "").isidentifier() else func
    raise ValueError(f"{where}: {message}")


@dataclass
class Topology:
    """Connectivity of a manifold, consistently oriented triangle mesh.

    Attributes
    ----------
    F : (m, 3) int64 numpy array
        Faces.
    n : int
        Number of vertices.
    E : (e, 2) int64 numpy array
        Undirected edges, ``E[:, 0] < E[:, 1]``.
    face_edge : (m, 3) int64 numpy array
        Edge id of face edge ``(F[f, c], F[f, (c + 1) % 3])``.
    sharpness : (e,) float64 numpy array
        Crease sharpness per edge (0 smooth, ``inf`` infinitely sharp);
        boundary edges are ``inf``.
    boundary : (e,) bool numpy array
        Edge has one incident face.
    """

    F: np.ndarray
    n: int
    E: np.ndarray
    face_edge: np.ndarray
    sharpness: np.ndarray
    boundary: np.ndarray

    @classmethod
    def build(cls, F: np.ndarray, n: int, sharpness_of=None) -> "Topology":
        """Build from faces; ``sharpness_of`` is ``(E_c (c,2), s (c,))`` or None."""
        F = np.asarray(F, dtype=np.int64)
        a = F.ravel()
        b = F[:, [1, 2, 0]].ravel()
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        keys = lo * n + hi
        uniq, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
        E = np.stack([uniq // n, uniq % n], axis=1)
        sharp = np.zeros(len(E))
        boundary = counts == 1
        sharp[boundary] = np.inf
        if sharpness_of is not None:
            Ec, sc = sharpness_of
            idx = np.searchsorted(uniq, np.minimum(Ec[:, 0], Ec[:, 1]) * n
                                  + np.maximum(Ec[:, 0], Ec[:, 1]))
            sharp[idx] = np.maximum(sharp[idx], sc)
        # Directed half-edge table for look-ups (v -> w) -> face, corner.
        he_keys = a * n + b
        order = np.argsort(he_keys)
        topo = cls(F, int(n), E, inverse.reshape(-1, 3), sharp, boundary)
        topo._he_sorted = he_keys[order]
        topo._he_index = order  # flat index f * 3 + c
        return topo

    # -- look-ups ---------------------------------------------------------
    def half_edge(self, v: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Flat corner index ``3 f + c`` of directed edge ``v -> w`` (``F[f, c] = v``), or -1."""
        v = np.asarray(v, dtype=np.int64)
        w = np.asarray(w, dtype=np.int64)
        valid = (v >= 0) & (w >= 0)
        key = np.where(valid, v * self.n + w, -1)
        pos = np.searchsorted(self._he_sorted, key)
        pos = np.minimum(pos, len(self._he_sorted) - 1)
        found = valid & (self._he_sorted[pos] == key)
        return np.where(found, self._he_index[pos], -1)

    def edge_id(self, v: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Undirected edge id of ``v - w`` (assumed to exist)."""
        c = self.half_edge(v, w)
        c = np.where(c < 0, self.half_edge(w, v), c)
        return self.face_edge.ravel()[c]

    def edge_sharp(self, v: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Whether edge ``v - w`` is sharp (boundary or crease with s > 0)."""
        return self.sharpness[self.edge_id(v, w)] > 0

    def next_ccw(self, v: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Neighbour of ``v`` following ``w`` counter-clockwise (through face ``v, w, x``), or -1."""
        c = self.half_edge(v, w)
        f, k = np.divmod(np.maximum(c, 0), 3)
        return np.where(c >= 0, self.F[f, (k + 2) % 3], -1)

    def next_cw(self, v: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Neighbour of ``v`` following ``w`` clockwise (through face ``w, v, y``), or -1."""
        c = self.half_edge(w, v)
        f, k = np.divmod(np.maximum(c, 0), 3)
        return np.where(c >= 0, self.F[f, (k + 2) % 3], -1)

    # -- per-vertex quantities -----------------------------------------------
    def valence(self) -> np.ndarray:
        """Number of incident edges per vertex, ``(n,)`` int."""
        return np.bincount(self.E.ravel(), minlength=self.n)

    def face_count(self) -> np.ndarray:
        """Number of incident faces per vertex, ``(n,)`` int."""
        return np.bincount(self.F.ravel(), minlength=self.n)

    def sharp_count(self) -> np.ndarray:
        """Number of incident sharp edges (boundary included) per vertex."""
        s = self.E[self.sharpness > 0].ravel()
        return np.bincount(s, minlength=self.n)

    def vertex_kind(self) -> np.ndarray:
        """Subdivision rule per vertex: 0 smooth (incl. dart), 1 crease, 2 corner."""
        sc = self.sharp_count()
        on_boundary = np.bincount(self.E[self.boundary].ravel(), minlength=self.n) > 0
        kind = np.where(sc >= 3, 2, np.where(sc == 2, 1, 0))
        kind[on_boundary & (self.face_count() == 1)] = 2
        return kind


def check_creases(creases, F: np.ndarray, n: int, func: str):
    """Normalise the ``creases`` argument to ``(E (c,2) int64, s (c,) float64)`` or None.

    Accepted forms: None; an int array ``(c, 2)`` of vertex pairs (infinitely
    sharp); a tuple ``(E, sharpness)`` with positive integer or ``inf`` sharpness.
    """
    if creases is None:
        return None
    if isinstance(creases, tuple) and len(creases) == 2:
        E, s = creases
    else:
        E, s = creases, None
    E = np.asarray(E)
    if E.size == 0:
        return None
    if E.ndim != 2 or E.shape[1] != 2 or not np.issubdtype(E.dtype, np.integer):
        _fail(func, f"creases must be an integer array of shape (c, 2), got {E.dtype} array of shape {E.shape}")
    E = E.astype(np.int64)
    s = np.full(len(E), np.inf) if s is None else np.asarray(s, dtype=np.float64).reshape(-1)
    if len(s) != len(E):
        _fail(func, f"got {len(E)} crease edges but {len(s)} sharpness values")
    bad = np.flatnonzero(~(s > 0) | (np.isfinite(s) & (s != np.round(s))))
    if len(bad):
        _fail(func, f"crease {bad[0]} has sharpness {s[bad[0]]}; expected a positive integer or inf")
    bad = np.flatnonzero(np.isfinite(s) & (s > 4))
    if len(bad):
        _fail(func, f"crease {bad[0]} has sharpness {s[bad[0]]:g}; finite sharpness above 4 is not supported (use inf)")
    bad = np.flatnonzero((E < 0).any(1) | (E >= n).any(1) | (E[:, 0] == E[:, 1]))
    if len(bad):
        _fail(func, f"crease {bad[0]} = {E[bad[0]].tolist()} is not a pair of distinct vertex indices in [0, {n})")
    keys = np.unique(np.sort(np.stack([F.ravel(), F[:, [1, 2, 0]].ravel()], 1), 1) @ [n, 1])
    ck = np.sort(E, 1) @ [n, 1]
    bad = np.flatnonzero(~np.isin(ck, keys))
    if len(bad):
        _fail(func, f"crease {bad[0]} = {E[bad[0]].tolist()} is not an edge of the mesh")
    return E, s


def validate_faces(F, n_vertices: int, func: str = "validate_mesh") -> np.ndarray:
    """Check connectivity; return faces as int64. Raises ValueError naming the problem."""
    F = np.asarray(F)
    if F.size == 0:
        _fail(func, "the mesh has no faces")
    if F.ndim != 2 or F.shape[1] != 3:
        _fail(func, f"faces must have shape (m, 3) (triangles only), got {F.shape}")
    if not np.issubdtype(F.dtype, np.integer):
        if np.issubdtype(F.dtype, np.floating) and np.all(F == np.round(F)):
            F = F.astype(np.int64)
        else:
            _fail(func, f"face indices must be integers, got dtype {F.dtype}")
    F = F.astype(np.int64)
    n = int(n_vertices)
    if n <= 0:
        _fail(func, "the mesh has no vertices")
    bad = np.flatnonzero((F < 0).any(1) | (F >= n).any(1))
    if len(bad):
        _fail(func, f"face {bad[0]} = {F[bad[0]].tolist()} has an index outside [0, {n})")
    bad = np.flatnonzero((F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0]))
    if len(bad):
        _fail(func, f"face {bad[0]} = {F[bad[0]].tolist()} is degenerate (repeated vertex)")
    a, b = F.ravel(), F[:, [1, 2, 0]].ravel()
    directed, counts = np.unique(a * n + b, return_counts=True)
    if (counts > 1).any():
        k = directed[np.argmax(counts > 1)]
        _fail(func, f"edge ({k // n}, {k % n}) is used twice in the same direction: "
                    "faces are inconsistently oriented or the edge is non-manifold")
    und, ucounts = np.unique(np.minimum(a, b) * n + np.maximum(a, b), return_counts=True)
    if (ucounts > 2).any():
        k = und[np.argmax(ucounts > 2)]
        _fail(func, f"edge ({k // n}, {k % n}) is non-manifold (shared by more than two faces)")
    _check_vertex_fans(F, n, func)
    return F


def _check_vertex_fans(F: np.ndarray, n: int, func: str):
    """Each vertex's incident faces must form a single fan (manifold vertex)."""
    m = len(F)
    corner_v = F.ravel()
    nxt = F[:, [1, 2, 0]].ravel()
    prv = F[:, [2, 0, 1]].ravel()
    # Corner A (edge v -> w leaving it) and corner B (edge w -> v entering it)
    # of the same vertex v belong to the same fan.
    key_in = prv * n + corner_v
    rev_out = nxt * n + corner_v
    order = np.argsort(key_in)
    pos = np.minimum(np.searchsorted(key_in[order], rev_out), 3 * m - 1)
    hit = key_in[order][pos] == rev_out
    A, B = np.flatnonzero(hit), order[pos[hit]]
    label = np.arange(3 * m)
    while True:  # label propagation to the smallest corner id of each fan
        new = label.copy()
        lo = np.minimum(label[A], label[B])
        np.minimum.at(new, A, lo)
        np.minimum.at(new, B, lo)
        new = new[new]
        if np.array_equal(new, label):
            break
        label = new
    fans = np.unique(np.stack([corner_v, label], 1), axis=0)
    per_vertex = np.bincount(fans[:, 0], minlength=n)
    bad = np.flatnonzero(per_vertex > 1)
    if len(bad):
        _fail(func, f"vertex {bad[0]} is non-manifold (its faces form {per_vertex[bad[0]]} separate fans)")


def validate_mesh(V, F, func: str = "validate_mesh"):
    """Validate a control mesh and drop unreferenced vertices.

    Parameters
    ----------
    V : (n, 3) float numpy array
        Vertex positions.
    F : (m, 3) int numpy array
        Triangle faces, consistently oriented, manifold (boundaries allowed).

    Returns
    -------
    V : (n', 3) float64 numpy array
        Referenced vertices only.
    F : (m, 3) int64 numpy array
        Faces re-indexed into ``V``.
    kept : (n',) int64 numpy array
        Original index of every kept vertex.

    Raises
    ------
    ValueError
        Empty mesh, non-triangle faces, out-of-range or negative indices,
        NaN/Inf coordinates, degenerate faces, non-manifold edges or vertices,
        inconsistent orientation; the message names the offending element.

    Warns
    -----
    UserWarning
        When unreferenced vertices are dropped (says how many).
    """
    V = np.asarray(V)
    if V.size == 0:
        _fail(func, "the mesh has no vertices")
    if V.ndim != 2 or V.shape[1] != 3:
        _fail(func, f"vertices must have shape (n, 3), got {V.shape}")
    if not np.issubdtype(V.dtype, np.number):
        _fail(func, f"vertex coordinates must be numbers, got dtype {V.dtype}")
    V = V.astype(np.float64)
    bad = np.flatnonzero(~np.isfinite(V).all(1))
    if len(bad):
        _fail(func, f"vertex {bad[0]} has a non-finite coordinate {V[bad[0]].tolist()}")
    F = validate_faces(F, len(V), func)
    used = np.zeros(len(V), bool)
    used[F.ravel()] = True
    kept = np.flatnonzero(used)
    if len(kept) < len(V):
        warnings.warn(f"{func}(): dropped {len(V) - len(kept)} unreferenced vertices", stacklevel=2)
        remap = np.full(len(V), -1, dtype=np.int64)
        remap[kept] = np.arange(len(kept))
        V, F = V[kept], remap[F]
    return V, F, kept
