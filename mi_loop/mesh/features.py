"""Sharp feature curves of a surface mesh, and the edges of a control mesh that follow them (NumPy/SciPy).

A feature edge of a mesh is an interior edge whose two faces meet at a
dihedral angle (between their normals) above a threshold; feature curves are
the connected chains of feature edges, and chains shorter than a minimum
length are dropped as noise (a scan's rough triangles, not a CAD part's
edges). A control mesh that was decimated from the data keeps its vertices on
those curves (quadric error metrics keep planes apart); its crease edges are
the control edges that are sharp themselves and lie on a data feature curve
along their whole length.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from mi_loop.mesh.geometry import face_normals
from mi_loop.mesh.halfedge import Topology

__all__ = ["FeatureCurves", "crease_edges", "dihedral_angles", "feature_curves"]


class FeatureCurves:
    """Feature edges of a mesh kept as chains, with a point sampling for distance queries.

    Build it with :func:`feature_curves`.

    Parameters
    ----------
    V : (n, 3) float64 NumPy array
        Vertices of the mesh.
    E : (c, 2) int64 NumPy array
        Its kept feature edges.
    angle : (c,) float64 NumPy array
        Their dihedral angles in degrees.
    n_curves : int
        Number of kept chains.
    spacing : float
        Typical edge length of the mesh (sets the sampling).

    Attributes
    ----------
    E : (c, 2) int64 NumPy array
        Feature edges (vertex pairs of the mesh).
    angle : (c,) float64 NumPy array
        Their dihedral angles in degrees.
    length : float
        Total length of the kept chains.
    n_curves : int
        Number of kept chains (connected components of feature edges).
    samples : (s, 3) float64 NumPy array
        Points along the feature edges, at most a quarter of ``spacing`` apart.
    """

    def __init__(self, V, E, angle, n_curves, spacing):
        self.E, self.angle, self.n_curves = E, angle, int(n_curves)
        seg = V[E[:, 1]] - V[E[:, 0]]
        lengths = np.linalg.norm(seg, axis=1)
        self.length = float(lengths.sum())
        steps = np.maximum(1, np.ceil(4 * lengths / spacing)).astype(np.int64)
        t = np.concatenate([np.arange(k + 1) / k for k in steps]) if len(E) else np.zeros(0)
        edge = np.repeat(np.arange(len(E)), steps + 1)
        self.samples = V[E[edge, 0]] + t[:, None] * seg[edge] if len(E) else np.zeros((0, 3))
        self._tree = cKDTree(self.samples) if len(self.samples) else None

    def distance(self, X: np.ndarray) -> np.ndarray:
        """Distance of points ``X (k, 3)`` to the nearest feature sample (``inf`` without features)."""
        if self._tree is None:
            return np.full(len(X), np.inf)
        return self._tree.query(X)[0]


def _dihedral(V, F):
    """Interior edges ``(e, 2)`` and the angle in degrees between the normals of their two faces."""
    topo = Topology.build(F, len(V))
    h = np.flatnonzero(topo.twin > np.arange(len(topo.twin)))        # one half-edge of every interior edge
    Nf = face_normals(V, F)
    cos = np.clip(np.einsum("ij,ij->i", Nf[h // 3], Nf[topo.twin[h] // 3]), -1.0, 1.0)
    return topo.E[topo.face_edge.ravel()[h]], np.degrees(np.arccos(cos))


def dihedral_angles(V, F) -> np.ndarray:
    """Angle in degrees between the normals of the two faces of every interior edge of a mesh.

    Parameters
    ----------
    V : (n, 3) float NumPy array
        Vertices.
    F : (m, 3) int NumPy array
        Triangles of a manifold, consistently oriented mesh (as :func:`mi_loop.validate_mesh` accepts).

    Returns
    -------
    (e,) float64 NumPy array

    Examples
    --------
    >>> V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.0]])
    >>> dihedral_angles(V, np.array([[0, 1, 2], [1, 3, 2]])).round(6).tolist()     # flat
    [0.0]
    """
    return _dihedral(np.asarray(V, dtype=np.float64), np.asarray(F, dtype=np.int64))[1]


def feature_curves(V, F, angle: float = 40.0, min_length: float = 0.0) -> FeatureCurves:
    """Feature curves of a triangle mesh: edges sharper than ``angle``, in chains of at least ``min_length``.

    Parameters
    ----------
    V : (n, 3) float NumPy array
        Vertices.
    F : (m, 3) int NumPy array
        Triangles of a manifold, consistently oriented mesh.
    angle : float
        Dihedral angle in degrees (between the face normals) above which an edge is a feature.
    min_length : float
        Chains (connected components of feature edges) shorter than this are dropped.

    Returns
    -------
    FeatureCurves

    Examples
    --------
    >>> V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    >>> F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    >>> curves = feature_curves(V, F, 40.0)
    >>> len(curves.E), curves.n_curves      # a tetrahedron: every edge is sharp, one connected chain
    (6, 1)
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    E, theta = _dihedral(V, F)
    keep = theta > angle
    E, theta = E[keep], theta[keep]
    spacing = float(np.median(np.linalg.norm(V[F[:, 1]] - V[F[:, 0]], axis=1))) if len(F) else 1.0
    if len(E) == 0:
        return FeatureCurves(V, E, theta, 0, spacing)
    G = sp.coo_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(len(V), len(V)))
    _, label = connected_components(G, directed=False)
    comp = label[E[:, 0]]
    lengths = np.bincount(comp, weights=np.linalg.norm(V[E[:, 1]] - V[E[:, 0]], axis=1))
    long = lengths[comp] >= min_length
    return FeatureCurves(V, E[long], theta[long], len(np.unique(comp[long])), spacing)


def crease_edges(V, F, curves: FeatureCurves, angle: float = 40.0, tolerance: float = 0.1) -> np.ndarray:
    """Edges of a control mesh ``(V, F)`` that follow the feature curves: the creases to tag.

    An edge qualifies when it is sharper than ``angle`` itself and its two end
    points and midpoint lie within ``tolerance`` (a fraction of the mean
    control edge length) of a feature curve.

    Parameters
    ----------
    V : (n, 3) float NumPy array
        Control points.
    F : (m, 3) int NumPy array
        Control faces.
    curves : FeatureCurves
        Feature curves of the data (:func:`feature_curves`).
    angle : float
        Dihedral angle in degrees above which a control edge may be a crease.
    tolerance : float
        Distance to the curves, relative to the mean control edge length.

    Returns
    -------
    (c, 2) int64 NumPy array
        Vertex pairs of the crease edges.
    """
    V = np.asarray(V, dtype=np.float64)
    E, theta = _dihedral(V, np.asarray(F, dtype=np.int64))
    if len(E) == 0 or curves.n_curves == 0:
        return np.zeros((0, 2), dtype=np.int64)
    mean_edge = float(np.linalg.norm(V[E[:, 1]] - V[E[:, 0]], axis=1).mean())
    near = tolerance * mean_edge
    ok = theta > angle
    for X in (V[E[:, 0]], V[E[:, 1]], 0.5 * (V[E[:, 0]] + V[E[:, 1]])):
        ok &= curves.distance(X) <= near
    return E[ok]
