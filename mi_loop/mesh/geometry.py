"""Geometry of triangle meshes (NumPy): normals, areas, edge lengths, components, welding.

The one place that computes these; every layer above calls it.
"""
from __future__ import annotations

import numpy as np

__all__ = ["adjacency", "connected_components", "edges", "euler_characteristic", "face_areas", "face_normals",
           "largest_component", "mean_edge_length", "vertex_normals", "weld"]


def _cross(V, F):
    return np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])


def face_normals(V, F) -> np.ndarray:
    """Unit face normals by the right-hand rule on ``F``.

    Parameters
    ----------
    V : (n, 3) float numpy array
    F : (m, 3) int numpy array

    Returns
    -------
    (m, 3) float64 numpy array
        Unit normals; zero for zero-area faces.

    Examples
    --------
    >>> face_normals(np.eye(3), np.array([[0, 1, 2]])).round(4).tolist()
    [[0.5774, 0.5774, 0.5774]]
    """
    n = _cross(np.asarray(V, dtype=np.float64), np.asarray(F))
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def face_areas(V, F) -> np.ndarray:
    """Return the triangle areas.

    Parameters
    ----------
    V : (n, 3) float numpy array
    F : (m, 3) int numpy array

    Returns
    -------
    (m,) float64 numpy array

    Examples
    --------
    >>> face_areas(np.eye(3), np.array([[0, 1, 2]])).round(4).tolist()
    [0.866]
    """
    return 0.5 * np.linalg.norm(_cross(np.asarray(V, dtype=np.float64), np.asarray(F)), axis=1)


def vertex_normals(V, F) -> np.ndarray:
    """Return area-weighted unit vertex normals (zero at unreferenced vertices).

    Parameters
    ----------
    V : (n, 3) float numpy array
    F : (m, 3) int numpy array

    Returns
    -------
    (n, 3) float64 numpy array

    Examples
    --------
    >>> vertex_normals(np.eye(3), np.array([[0, 1, 2]])).round(4).tolist()[0]
    [0.5774, 0.5774, 0.5774]
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F)
    Fn = _cross(V, F)
    N = np.zeros_like(V)
    for c in range(3):
        np.add.at(N, F[:, c], Fn)
    return N / np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-30)


def edges(F) -> np.ndarray:
    """Return the undirected edges of a triangle mesh, each once.

    Parameters
    ----------
    F : (m, 3) int numpy array

    Returns
    -------
    (e, 2) int64 numpy array
        Rows ``(a, b)`` with ``a < b``, sorted.

    Examples
    --------
    >>> edges(np.array([[0, 1, 2], [0, 2, 3]])).tolist()
    [[0, 1], [0, 2], [0, 3], [1, 2], [2, 3]]
    """
    F = np.asarray(F, dtype=np.int64)
    E = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), 1)
    return np.unique(E, axis=0)


def adjacency(F, n: int):
    """Return the vertex adjacency matrix of a triangle mesh.

    Parameters
    ----------
    F : (m, 3) int NumPy array
        Triangles.
    n : int
        Number of vertices.

    Returns
    -------
    (n, n) scipy.sparse.csr_matrix, float64
        ``A_ij = 1`` where ``i`` and ``j`` share an edge; its row sums are the valences.

    Examples
    --------
    >>> adjacency(np.array([[0, 1, 2]]), 4).sum(axis=1).A1.tolist()
    [2.0, 2.0, 2.0, 0.0]
    """
    import scipy.sparse as sp

    E = edges(np.asarray(F))
    return sp.coo_matrix((np.ones(2 * len(E)), (np.r_[E[:, 0], E[:, 1]], np.r_[E[:, 1], E[:, 0]])),
                         shape=(n, n)).tocsr()


def mean_edge_length(V, F) -> float:
    """Return the mean length of the face edges (an edge shared by two faces counts twice).

    Parameters
    ----------
    V : (n, 3) float numpy array
    F : (m, 3) int numpy array

    Returns
    -------
    float

    Examples
    --------
    >>> mean_edge_length(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]))
    1.1380711874576983
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F)
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    return float(np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1).mean())


def connected_components(n_vertices: int, F) -> tuple[int, np.ndarray]:
    """Return the connected components of the vertices through the faces.

    Parameters
    ----------
    n_vertices : int
        Number of vertices ``n``.
    F : (m, 3) int numpy array
        Faces, indices in ``[0, n)``.

    Returns
    -------
    count : int
        Components, unreferenced vertices counted as their own.
    label : (n,) int numpy array
        Component of every vertex.

    Examples
    --------
    >>> count, label = connected_components(7, np.array([[0, 1, 2], [3, 4, 5]]))
    >>> count, label.tolist()
    (3, [0, 0, 0, 1, 1, 1, 2])
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components as components

    F = np.asarray(F, dtype=np.int64)
    i, j = F.ravel(), F[:, [1, 2, 0]].ravel()
    A = coo_matrix((np.ones(len(i)), (i, j)), shape=(n_vertices, n_vertices))
    return components(A, directed=False)


def largest_component(V, F) -> tuple[np.ndarray, np.ndarray]:
    """Return the connected component with the most faces, without unreferenced vertices.

    Parameters
    ----------
    V : (n, 3) float numpy array
    F : (m, 3) int numpy array

    Returns
    -------
    V : (n', 3) numpy array
        Vertices of the component, in their original order.
    F : (m', 3) int64 numpy array
        Its faces, re-indexed into the returned ``V``.

    Examples
    --------
    >>> V = np.arange(21.0).reshape(7, 3)
    >>> V2, F2 = largest_component(V, np.array([[0, 1, 2], [4, 5, 6], [4, 6, 3]]))
    >>> V2[:, 0].tolist(), F2.tolist()
    ([9.0, 12.0, 15.0, 18.0], [[1, 2, 3], [1, 3, 0]])
    """
    _, label = connected_components(len(V), F)
    face_label = label[F[:, 0]]
    F = F[face_label == np.argmax(np.bincount(face_label))]
    used = np.unique(F)
    remap = np.full(len(V), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return V[used], remap[F]


def weld(V, F) -> tuple[np.ndarray, np.ndarray]:
    """Merge vertices with identical coordinates and drop the faces that collapse.

    A triangle soup (three vertices per face) becomes an indexed mesh. Arrays
    that are not a valid triangle list are returned unchanged, so the caller's
    validation names the problem.

    Parameters
    ----------
    V : (n, 3) float numpy array
    F : (m, 3) int numpy array

    Returns
    -------
    V : (n', 3) numpy array
        Distinct vertices, sorted by coordinates (``numpy.unique`` order).
    F : (m', 3) int numpy array
        Faces re-indexed into them, those with a repeated vertex dropped.

    Examples
    --------
    >>> V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    >>> weld(V, np.array([[0, 1, 2], [3, 5, 4]]))[1].tolist()
    [[0, 2, 1], [2, 3, 1]]
    """
    V, F = np.asarray(V), np.asarray(F)
    if F.ndim != 2 or F.shape[1] != 3 or len(V) == 0 or F.size == 0 or F.min() < 0 or F.max() >= len(V):
        return V, F
    U, inverse = np.unique(V, axis=0, return_inverse=True)
    if len(U) == len(V):
        return V, F
    F = inverse.ravel()[F]
    keep = (F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 2] != F[:, 0])
    return U, F[keep]


def euler_characteristic(n_vertices: int, F) -> tuple[int, int]:
    """Return the Euler characteristic ``V - E + F`` and the number of boundary edges.

    Parameters
    ----------
    n_vertices : int
        Number of vertices ``V`` (unreferenced ones count).
    F : (m, 3) int numpy array
        Faces.

    Returns
    -------
    chi : int
    n_boundary : int
        Edges with one incident face.

    Examples
    --------
    >>> euler_characteristic(4, np.array([[0, 2, 1], [0, 3, 2], [0, 1, 3], [1, 2, 3]]))
    (2, 0)
    """
    F = np.asarray(F, dtype=np.int64)
    _, counts = np.unique(np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), 1),
                          axis=0, return_counts=True)
    return n_vertices - len(counts) + len(F), int((counts == 1).sum())
