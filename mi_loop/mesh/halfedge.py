"""Half-edge adjacency of a validated triangle mesh (NumPy): the :class:`Topology` that subdivision walks.

Build it from faces that :func:`mi_loop.mesh.topology.validate_faces` accepted;
nothing here checks its input.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Topology"]


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
    """

    F: np.ndarray
    n: int
    E: np.ndarray
    face_edge: np.ndarray
    sharpness: np.ndarray
    boundary: np.ndarray

    @classmethod
    def build(cls, F: np.ndarray, n: int, sharpness_of=None) -> Topology:
        """Build the connectivity of validated faces.

        Parameters
        ----------
        F : (m, 3) int numpy array
            Faces, already checked by :func:`mi_loop.mesh.topology.validate_faces`.
        n : int
            Number of vertices.
        sharpness_of : tuple ``(E_c (c, 2) int numpy array, s (c,) float numpy array)`` or None
            Crease edges and their sharpness, as returned by :func:`check_creases`.

        Returns
        -------
        Topology
        """
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
        """Flat corner index ``3 f + c`` of the directed edges ``v -> w`` (``F[f, c] = v``).

        Parameters
        ----------
        v, w : (k,) int numpy arrays
            Start and end vertices; negative entries give -1.

        Returns
        -------
        (k,) int64 numpy array
            Corner index, or -1 where no face has the directed edge.
        """
        v = np.asarray(v, dtype=np.int64)
        w = np.asarray(w, dtype=np.int64)
        valid = (v >= 0) & (w >= 0)
        key = np.where(valid, v * self.n + w, -1)
        pos = np.searchsorted(self._he_sorted, key)
        pos = np.minimum(pos, len(self._he_sorted) - 1)
        found = valid & (self._he_sorted[pos] == key)
        return np.where(found, self._he_index[pos], -1)

    def edge_id(self, v: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Undirected edge ids of the edges ``v - w``.

        Parameters
        ----------
        v, w : (k,) int numpy arrays
            End vertices of existing edges (not checked).

        Returns
        -------
        (k,) int64 numpy array
            Rows of :attr:`E`.
        """
        c = self.half_edge(v, w)
        c = np.where(c < 0, self.half_edge(w, v), c)
        return self.face_edge.ravel()[c]

    def edge_sharp(self, v: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Whether the edges ``v - w`` are sharp (boundary, or crease with sharpness > 0).

        Parameters
        ----------
        v, w : (k,) int numpy arrays
            End vertices of existing edges.

        Returns
        -------
        (k,) bool numpy array
        """
        return self.sharpness[self.edge_id(v, w)] > 0

    def next_ccw(self, v: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Neighbour of ``v`` following ``w`` counter-clockwise (through face ``v, w, x``).

        Parameters
        ----------
        v, w : (k,) int numpy arrays
            Centre vertices and one neighbour of each.

        Returns
        -------
        (k,) int64 numpy array
            ``x``, or -1 where there is no such face (boundary).
        """
        c = self.half_edge(v, w)
        f, k = np.divmod(np.maximum(c, 0), 3)
        return np.where(c >= 0, self.F[f, (k + 2) % 3], -1)

    def next_cw(self, v: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Neighbour of ``v`` following ``w`` clockwise (through face ``w, v, y``).

        Parameters
        ----------
        v, w : (k,) int numpy arrays
            Centre vertices and one neighbour of each.

        Returns
        -------
        (k,) int64 numpy array
            ``y``, or -1 where there is no such face (boundary).
        """
        c = self.half_edge(w, v)
        f, k = np.divmod(np.maximum(c, 0), 3)
        return np.where(c >= 0, self.F[f, (k + 2) % 3], -1)

    # -- per-vertex quantities -----------------------------------------------
    def valence(self) -> np.ndarray:
        """Return the number of incident edges per vertex.

        Returns
        -------
        (n,) int64 numpy array
        """
        return np.bincount(self.E.ravel(), minlength=self.n)

    def face_count(self) -> np.ndarray:
        """Return the number of incident faces per vertex.

        Returns
        -------
        (n,) int64 numpy array
        """
        return np.bincount(self.F.ravel(), minlength=self.n)

    def sharp_count(self) -> np.ndarray:
        """Return the number of incident sharp edges (boundary edges included) per vertex.

        Returns
        -------
        (n,) int64 numpy array
        """
        s = self.E[self.sharpness > 0].ravel()
        return np.bincount(s, minlength=self.n)

    def vertex_kind(self) -> np.ndarray:
        """Return the subdivision rule of every vertex.

        Returns
        -------
        (n,) int64 numpy array
            0 smooth (a dart included), 1 crease (two sharp edges), 2 corner
            (three or more sharp edges, or a boundary vertex with one face).
        """
        sc = self.sharp_count()
        on_boundary = np.bincount(self.E[self.boundary].ravel(), minlength=self.n) > 0
        kind = np.where(sc >= 3, 2, np.where(sc == 2, 1, 0))
        kind[on_boundary & (self.face_count() == 1)] = 2
        return kind
