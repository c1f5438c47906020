"""Cut a closed mesh's handles: the shortest non-separating loops, cut open and capped.

A screened Poisson surface fine enough to keep a body's armpits open also
joins the arm to the torso wherever they touch: each contact is a short tube,
a handle of the surface. :func:`cut_handles` removes such handles one at a
time. For every vertex ``r`` it builds the greedy homotopy basis at ``r``
(Erickson and Whittlesey 2005, "Greedy optimal homotopy and homology
generators"): the shortest-path tree from ``r``; a maximum spanning tree of
the dual graph of the other edges, each edge ``e = (u, v)`` weighed by the
length of its loop ``path(r, u) + e + path(v, r)``; the ``2g`` edges left
over close the basis, and the shortest of their loops is the shortest
non-separating loop through ``r``. The shortest over every ``r`` is cut: its
vertices are split in two along it, and each of the two holes is capped by a
fan around a new vertex set a little back along its own side. Each cut lowers
the genus by one and keeps the mesh closed and manifold.

A contact's loop is its tube's girth, far shorter than any loop around a
limb, so it goes first. A real handle (a mug's) is cut too: the caller says
what genus the subject has.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra, minimum_spanning_tree

from mi_loop.errors import fail
from mi_loop.mesh.geometry import euler_characteristic

__all__ = ["cut_handles", "shortest_handle_loop"]

#: Roots whose shortest paths are computed together (memory: ``CHUNK`` rows of the vertex count).
CHUNK = 256


def _edges(F):
    """Unique edges ``(m, 2)`` and, per edge, its two faces ``(m, 2)`` (a closed manifold mesh)."""
    he = np.stack([F, np.roll(F, -1, axis=1)], axis=2).reshape(-1, 2)
    key = np.sort(he, axis=1)
    E, inverse = np.unique(key, axis=0, return_inverse=True)
    order = np.argsort(inverse, kind="stable")
    faces = (order // 3).reshape(-1, 2)
    return E, faces


def _path(pred, v):
    """Vertices from ``v`` up the shortest-path tree to its root."""
    out = [int(v)]
    while pred[out[-1]] >= 0:
        out.append(int(pred[out[-1]]))
    return out


def shortest_handle_loop(V, F):
    """The shortest non-separating loop of a closed manifold mesh of genus >= 1 (module docstring).

    Parameters
    ----------
    V : (n, 3) float array-like
        Vertices.
    F : (m, 3) int array-like
        Triangles of one closed, oriented, manifold component.

    Returns
    -------
    loop : list of int
        The loop's vertices in order, without repeats (it closes from the last back to the first).
    length : float
        Its length.

    Raises
    ------
    ValueError
        When the mesh is not closed or has genus 0 (no handle to cut).
    """
    V, F = np.asarray(V, dtype=np.float64), np.asarray(F, dtype=np.int64)
    chi, n_boundary = euler_characteristic(len(V), F)
    if n_boundary:
        fail("shortest_handle_loop", "a closed mesh", f"{n_boundary} boundary edges")
    if chi >= 2:
        fail("shortest_handle_loop", "a mesh of genus >= 1", "genus 0")
    E, EF = _edges(F)
    w = np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)
    n = len(V)
    G = sp.coo_matrix((np.r_[w, w], (np.r_[E[:, 0], E[:, 1]], np.r_[E[:, 1], E[:, 0]])), shape=(n, n)).tocsr()
    best = (np.inf, None, None, None)
    for r in range(n):
        if r % CHUNK == 0:        # shortest paths from CHUNK roots at a time: memory O(CHUNK n)
            dist, pred = dijkstra(G, indices=np.arange(r, min(r + CHUNK, n)), return_predecessors=True)
        d, p = dist[r % CHUNK], pred[r % CHUNK]
        tree = (p[E[:, 0]] == E[:, 1]) | (p[E[:, 1]] == E[:, 0])
        other = np.flatnonzero(~tree)
        loop = d[E[other, 0]] + d[E[other, 1]] + w[other]
        # the dual's maximum spanning tree by loop length (positive weights: scipy drops zeros)
        weight = loop.max() + 1.0 - loop
        a, b = EF[other, 0], EF[other, 1]
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        pair = lo * len(F) + hi
        uniq, first = np.unique(pair, return_index=True)     # a face pair sharing two edges: keep one
        T = minimum_spanning_tree(sp.coo_matrix((weight[first], (lo[first], hi[first])), shape=(len(F),) * 2))
        T = T.tocoo()
        in_cotree = np.zeros(len(other), bool)
        in_cotree[first[np.searchsorted(uniq, T.row.astype(np.int64) * len(F) + T.col)]] = True
        left = np.flatnonzero(~in_cotree)
        if len(left) == 0:
            continue
        k = left[np.argmin(loop[left])]
        if loop[k] < best[0]:
            best = (float(loop[k]), r, other[k], p.copy())
    _, r, e, p = best
    u, v = E[e]
    pu, pv = _path(p, u), _path(p, v)
    while len(pu) > 1 and len(pv) > 1 and pu[-2] == pv[-2]:      # strip the shared stem to the lowest ancestor
        pu.pop()
        pv.pop()
    cycle = pu + pv[:-1][::-1]
    return cycle, float(np.sum(np.linalg.norm(V[cycle] - V[np.roll(cycle, -1)], axis=1)))


def _cut(V, F, cycle):
    """Split the mesh along ``cycle`` and cap both holes (module docstring)."""
    F = F.copy()
    k = len(cycle)
    face_of = {}
    for f, (a, b, c) in enumerate(F):
        face_of[(a, b)], face_of[(b, c)], face_of[(c, a)] = f, f, f
    left = set()
    for i, c in enumerate(cycle):
        nxt, prv = cycle[(i + 1) % k], cycle[i - 1]
        f = face_of[(c, nxt)]
        while True:                           # counter-clockwise around c, from the outgoing edge to the incoming one
            left.add((f, c))
            tri = list(F[f])
            y = tri[(tri.index(c) + 2) % 3]
            if y == prv:
                break
            f = face_of[(c, y)]
    new = {c: len(V) + i for i, c in enumerate(cycle)}
    for f, c in left:
        F[f][list(F[f]).index(c)] = new[c]
    ring = np.array(cycle)
    centre = V[ring].mean(axis=0)
    # each cap's centre: half way from the loop's centre to the mean of the vertices next to the loop on its side
    beside_left = np.setdiff1d(F[sorted({f for f, _ in left})], list(new.values()))
    beside_right = np.setdiff1d(F[np.isin(F, ring).any(axis=1)], ring)
    sides = [centre + 0.5 * (V[beside].mean(axis=0) - centre) for beside in (beside_left, beside_right)]
    V = np.vstack([V, V[ring], sides])
    pl, pr = len(V) - 2, len(V) - 1
    caps = []
    for i in range(k):
        a, b = cycle[i], cycle[(i + 1) % k]
        caps.append((new[b], new[a], pl))    # the left hole: its faces hold new[a] -> new[b]
        caps.append((a, b, pr))              # the right hole: its faces hold b -> a
    return V, np.vstack([F, np.array(caps, dtype=F.dtype)])


def cut_handles(V, F, genus: int = 0, max_cuts: int = 64):
    """Cut the shortest handle loops of a closed manifold mesh until its genus is ``genus``.

    Parameters
    ----------
    V : (n, 3) float array-like
        Vertices.
    F : (m, 3) int array-like
        Triangles of one closed, oriented, manifold component.
    genus : int
        The genus to reach (>= 0); a mesh already at or below it is returned as it is.
    max_cuts : int
        Most handles cut; more than that raises.

    Returns
    -------
    V : (n', 3) float64 NumPy array
    F : (m', 3) int64 NumPy array
        Closed, oriented and manifold, of genus ``min(genus, the input's)``.
    loops : list of float
        The length of each loop cut, in order.

    Raises
    ------
    ValueError
        Not closed, ``genus < 0``, or more than ``max_cuts`` handles to cut.
    """
    V, F = np.asarray(V, dtype=np.float64), np.asarray(F, dtype=np.int64)
    if not (isinstance(genus, (int, np.integer)) and genus >= 0):
        fail("cut_handles", "genus an integer >= 0", repr(genus))
    chi, n_boundary = euler_characteristic(len(V), F)
    if n_boundary:
        fail("cut_handles", "a closed mesh", f"{n_boundary} boundary edges")
    have = (2 - chi) // 2
    if have - genus > max_cuts:
        fail("cut_handles", f"at most {max_cuts} handles to cut", f"genus {have} down to {genus}")
    loops = []
    while have > genus:
        cycle, length = shortest_handle_loop(V, F)
        V, F = _cut(V, F, cycle)
        loops.append(length)
        have = (2 - euler_characteristic(len(V), F)[0]) // 2
    return V, F, loops
