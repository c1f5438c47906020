"""Half-edge adjacency of a validated triangle mesh (NumPy): the :class:`Topology` that subdivision walks.

Build it from faces that :func:`mi_loop.mesh.topology.validate_faces` accepted;
nothing here checks its input.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["HalfEdgeTables", "Topology"]


@dataclass
class Topology:
    """Connectivity of a manifold, consistently oriented triangle mesh.

    Build it with :meth:`Topology.build`; the constructor only stores the arrays.

    Parameters
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
    twin : (3 m,) int64 numpy array, optional
        Half-edge ``v -> w`` (flat corner index ``3 f + c`` of ``F[f, c] = v``,
        ``F[f, (c + 1) % 3] = w``) to its opposite ``w -> v``, -1 on a
        boundary; derived from ``F`` and ``face_edge`` when not given.
    vertex_sharpness : (n,) float64 numpy array, optional
        OpenSubdiv's vertex sharpness (0 none, ``inf`` an infinitely sharp
        corner); zeros when not given.
    crease_method : str
        ``'uniform'`` or ``'chaikin'``: how semi-sharp edges decay.
    hole : (m,) bool numpy array, optional
        Faces that are holes (boundary rule ``'none'``): subdivided like the
        others, but not part of the limit surface; none when not given.

    Notes
    -----
    Edges are identified by their two end vertices, so a mesh in which two
    distinct edges join the same pair of vertices cannot be represented;
    :func:`mi_loop.mesh.topology.validate_faces` refuses the only valid
    triangle meshes whose Loop refinement has such double edges (two faces
    on the same three vertices).

    Examples
    --------
    >>> topo = Topology.build(np.array([[0, 1, 2], [0, 2, 3]]), 4)
    >>> topo.E.tolist(), topo.boundary.tolist()
    ([[0, 1], [0, 2], [0, 3], [1, 2], [2, 3]], [True, False, True, True, True])
    >>> topo.valence().tolist(), topo.vertex_kind().tolist()
    ([3, 2, 3, 2], [1, 2, 1, 2])
    >>> topo.twin.tolist()     # corner 2 of face 0 (2 -> 0) is opposite corner 0 of face 1 (0 -> 2)
    [-1, -1, 3, 2, -1, -1]
    """

    F: np.ndarray
    n: int
    E: np.ndarray
    face_edge: np.ndarray
    sharpness: np.ndarray
    boundary: np.ndarray
    twin: np.ndarray | None = None
    vertex_sharpness: np.ndarray | None = None
    crease_method: str = "uniform"
    hole: np.ndarray | None = None

    def __post_init__(self):
        if self.twin is None:
            self.twin = _twins(np.asarray(self.face_edge).ravel())
        if self.vertex_sharpness is None:
            self.vertex_sharpness = np.zeros(self.n)
        if self.hole is None:
            self.hole = np.zeros(len(self.F), dtype=bool)
        self._walk = None           # half-edge tables for the walks, built on first use

    @classmethod
    def build(cls, F: np.ndarray, n: int, sharpness_of=None, corners_of=None,
              boundary: str = "edge_and_corner", crease_method: str = "uniform") -> Topology:
        """Build the connectivity of validated faces.

        Parameters
        ----------
        F : (m, 3) int numpy array
            Faces, already checked by :func:`mi_loop.mesh.topology.validate_faces`.
        n : int
            Number of vertices.
        sharpness_of : tuple ``(E_c (c, 2) int numpy array, s (c,) float numpy array)`` or None
            Crease edges and their sharpness, as returned by :func:`check_creases`.
        corners_of : tuple ``(ids (c,) int numpy array, s (c,) float numpy array)`` or None
            Vertex sharpness, as returned by :func:`check_corners`.
        boundary : str
            OpenSubdiv's boundary interpolation (see
            :func:`mi_loop.mesh.topology.sharp_topology`): ``'edge_and_corner'``
            makes a boundary vertex of one face an infinitely sharp corner;
            ``'none'`` marks holes; ``'edge_only'`` neither.
        crease_method : str
            Kept for :func:`~mi_loop.subdiv.subdivision.subdivide_topology`.

        Returns
        -------
        Topology
        """
        F = np.asarray(F, dtype=np.int64)
        a = F.ravel()
        b = F[:, [1, 2, 0]].ravel()
        keys = np.minimum(a, b) * n + np.maximum(a, b)
        # One sort gives the edges (sorted keys), the edge of every corner and
        # the twins: the two half-edges of an interior edge are neighbours.
        order = np.argsort(keys)
        sorted_keys = keys[order]
        first = np.ones(len(keys), dtype=bool)
        first[1:] = sorted_keys[1:] != sorted_keys[:-1]
        uniq = sorted_keys[first]
        face_edge = np.empty(len(keys), dtype=np.int64)
        face_edge[order] = np.cumsum(first) - 1
        E = np.stack([uniq // n, uniq % n], axis=1)
        paired = np.flatnonzero(~first)             # order[i] and order[i - 1] share an edge
        twin = np.full(len(keys), -1, dtype=np.int64)
        twin[order[paired]], twin[order[paired - 1]] = order[paired - 1], order[paired]
        is_boundary = np.ones(len(E), dtype=bool)
        is_boundary[face_edge[order[paired]]] = False
        given = np.zeros(len(E))
        if sharpness_of is not None:
            Ec, sc = sharpness_of
            idx = np.searchsorted(uniq, np.minimum(Ec[:, 0], Ec[:, 1]) * n
                                  + np.maximum(Ec[:, 0], Ec[:, 1]))
            np.maximum.at(given, idx, sc)
        sharp = np.where(is_boundary, np.inf, given)         # boundary edges are infinitely sharp
        vs = np.zeros(int(n))
        if corners_of is not None:
            np.maximum.at(vs, corners_of[0], corners_of[1])
        on_boundary = np.bincount(E[is_boundary].ravel(), minlength=n)
        faces_at = np.bincount(F.ravel(), minlength=n)
        if boundary == "edge_and_corner":
            vs[(faces_at == 1) & (on_boundary == 2)] = np.inf
        hole = None
        if boundary == "none":
            # OpenSubdiv: the faces at a boundary vertex with a boundary edge not given as infinitely sharp
            soft = np.bincount(E[is_boundary & ~np.isinf(given)].ravel(), minlength=n) > 0
            hole = soft[F].any(1)
        return cls(F, int(n), E, face_edge.reshape(-1, 3), sharp, is_boundary, twin, vs, crease_method, hole)

    # -- half-edge walks -----------------------------------------------------
    def walk_tables(self) -> HalfEdgeTables:
        """Return the look-up tables of the half-edge walks (built once per topology).

        Returns
        -------
        HalfEdgeTables
        """
        if self._walk is None:
            self._walk = HalfEdgeTables.of(self)
        return self._walk

    # -- per-vertex quantities -----------------------------------------------
    def valence(self) -> np.ndarray:
        """Return the number of incident edges per vertex.

        Returns
        -------
        (n,) int64 numpy array
        """
        return np.bincount(self.E.ravel(), minlength=self.n)

    def sharp_count(self) -> np.ndarray:
        """Return the number of incident sharp edges (boundary edges included) per vertex.

        Returns
        -------
        (n,) int64 numpy array
        """
        s = self.E[self.sharpness > 0].ravel()
        return np.bincount(s, minlength=self.n)

    def vertex_kind(self) -> np.ndarray:
        """Return the subdivision rule of every vertex (OpenSubdiv's ``DetermineVertexVertexRule``).

        Returns
        -------
        (n,) int64 numpy array
            0 smooth (a dart included), 1 crease (two sharp edges), 2 corner
            (vertex sharpness > 0, e.g. a boundary vertex with one face under
            the edge-and-corner rule, or three or more sharp edges).
        """
        sc = self.sharp_count()
        kind = np.where(sc >= 3, 2, np.where(sc == 2, 1, 0))
        kind[self.vertex_sharpness > 0] = 2
        return kind


def _twins(corner_edge: np.ndarray) -> np.ndarray:
    """Opposite half-edge of every corner, -1 on a boundary, from the edge id of every corner."""
    order = np.argsort(corner_edge, kind="stable")
    paired = np.flatnonzero(corner_edge[order][1:] == corner_edge[order][:-1]) + 1
    twin = np.full(len(corner_edge), -1, dtype=np.int64)
    twin[order[paired]], twin[order[paired - 1]] = order[paired - 1], order[paired]
    return twin


@dataclass
class HalfEdgeTables:
    """Look-up tables that turn ring walks into direct indexing.

    Half-edge ``h = 3 f + c`` runs from ``F[f, c]`` (its tail) to
    ``F[f, (c + 1) % 3]`` (its head). Every table has one entry per half-edge
    and a last entry for ``h = -1`` (-1, or True for the sharpness tables), so
    a walk that has ended stays ended without masks. Build it with
    :meth:`Topology.walk_tables`.

    Parameters
    ----------
    head : (3 m + 1,) int64 numpy array
        Head vertex.
    prev_vertex : (3 m + 1,) int64 numpy array
        Third vertex of the face: the neighbour of the tail that follows the
        head counter-clockwise.
    ccw : (3 m + 1,) int64 numpy array
        Half-edge from the tail to ``prev_vertex`` (the next one
        counter-clockwise around the tail), -1 across a boundary.
    cw : (3 m + 1,) int64 numpy array
        Half-edge from the tail to the neighbour that precedes the head
        (the next one clockwise), -1 across a boundary.
    sharp : (3 m + 1,) bool numpy array
        The edge of the half-edge is sharp (boundary, or crease with sharpness > 0).
    prev_sharp : (3 m + 1,) bool numpy array
        The edge from the tail to ``prev_vertex`` is sharp.

    Examples
    --------
    >>> topo = Topology.build(np.array([[0, 1, 2], [0, 2, 3]]), 4)
    >>> T = topo.walk_tables()
    >>> int(T.head[0]), int(T.prev_vertex[0]), int(T.ccw[0]), int(T.ccw[T.ccw[0]])   # around vertex 0 from 1
    (1, 2, 3, -1)
    """

    head: np.ndarray
    prev_vertex: np.ndarray
    ccw: np.ndarray
    cw: np.ndarray
    sharp: np.ndarray
    prev_sharp: np.ndarray

    @classmethod
    def of(cls, topo: Topology) -> HalfEdgeTables:
        """Build the tables of a topology (see :meth:`Topology.walk_tables`)."""
        m3 = 3 * len(topo.F)
        h = np.arange(m3).reshape(-1, 3)
        nxt, prv = h[:, [1, 2, 0]].ravel(), h[:, [2, 0, 1]].ravel()
        corner_vertex = topo.F.ravel()
        twin = topo.twin

        def padded(a, end):
            return np.append(a, np.asarray(end, dtype=a.dtype))

        sharp = topo.sharpness[topo.face_edge.ravel()] > 0
        return cls(head=padded(corner_vertex[nxt], -1), prev_vertex=padded(corner_vertex[prv], -1),
                   ccw=padded(twin[prv], -1), cw=padded(np.where(twin >= 0, nxt[twin], -1), -1),
                   sharp=padded(sharp, True), prev_sharp=padded(sharp[prv], True))
