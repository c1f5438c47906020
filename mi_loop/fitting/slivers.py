"""Sliver removal for decimated control meshes: edge flips, tangential relaxation, collapses.

Quadric decimation leaves needles and caps; a Loop control mesh with angles
near 0 or 180 degrees gives badly shaped patches. :func:`remove_slivers`
raises the smallest angle to a bound with three local operations, each kept
on a reference surface (the Poisson surface or the refined input mesh):
flipping the edge opposite a cap's large angle, moving vertices toward their
one-ring centroid in the tangent plane and projecting them back, and
collapsing the shortest edge of a needle where topology allows.
"""
from __future__ import annotations

import numpy as np

from mi_loop.mesh.geometry import face_normals

__all__ = ["angles", "remove_slivers"]


def angles(V, F):
    """Return the corner angles of every triangle in degrees.

    Parameters
    ----------
    V : (n, 3) float NumPy array
        Vertices.
    F : (m, 3) int NumPy array
        Triangles.

    Returns
    -------
    (m, 3) float64 NumPy array
        Angle of corner ``c`` of face ``f`` (at vertex ``F[f, c]``), in [0, 180].

    Examples
    --------
    >>> angles(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]])).round(6).tolist()
    [[90.0, 45.0, 45.0]]
    """
    T = V[F]
    e1 = np.roll(T, -1, axis=1) - T
    e2 = np.roll(T, -2, axis=1) - T
    num = np.einsum("mci,mci->mc", e1, e2)
    den = np.linalg.norm(e1, axis=2) * np.linalg.norm(e2, axis=2)
    return np.degrees(np.arccos(np.clip(num / np.maximum(den, 1e-300), -1.0, 1.0)))


def remove_slivers(V, F, Vp, Fp, min_angle, rounds: int = 8):
    """Raise the smallest angle of a closed triangle mesh towards ``min_angle``.

    Each round flips the edge opposite the large angle of caps, relaxes the
    vertices of bad faces tangentially (projected back onto the reference
    surface ``(Vp, Fp)``) and collapses the shortest edge of the needles that
    remain, where the topology allows.

    Parameters
    ----------
    V : (n, 3) float64 NumPy array
        Vertices of the mesh to clean (closed, consistently oriented).
    F : (m, 3) int64 NumPy array
        Its triangles.
    Vp : (p, 3) float64 NumPy array
        Vertices of the reference surface (the Poisson surface or the refined input mesh).
    Fp : (q, 3) int64 NumPy array
        Its triangles.
    min_angle : float
        Target smallest corner angle, degrees.
    rounds : int, optional
        Most rounds of the three operations; stops early once no angle is below ``min_angle``.

    Returns
    -------
    V : (n', 3) float64 NumPy array
        Vertices (fewer after collapses).
    F : (m', 3) int64 NumPy array
        Triangles.
    stats : dict
        ``min_angle`` (the smallest angle reached, degrees), ``flips``, ``collapses``.
    """
    flips = collapses = 0
    for _ in range(rounds):
        bad = np.flatnonzero(angles(V, F).min(1) < min_angle)
        if len(bad) == 0:
            break
        F, k = _flip_caps(V, F, bad)
        flips += k
        bad = np.flatnonzero(angles(V, F).min(1) < min_angle)
        V = _relax(V, F, np.unique(F[bad]), Vp, Fp) if len(bad) else V
        bad = np.flatnonzero(angles(V, F).min(1) < min_angle)
        if len(bad):
            V, F, k = _collapse_short_edges(V, F, bad, Vp, Fp)
            collapses += k
    return V, F, {"min_angle": float(angles(V, F).min()), "flips": flips, "collapses": collapses}


def _flip_caps(V, F, bad):
    """Flip the edge opposite the largest angle of each bad face when that raises the pair's min angle."""
    F = F.copy()
    he = {(int(a), int(b)): f for f, row in enumerate(F) for a, b in zip(row, np.roll(row, -1))}
    valence = np.bincount(F.ravel(), minlength=len(V))   # closed mesh: faces = edges per vertex
    done, flips = set(), 0
    for f in bad[np.argsort(angles(V, F[bad]).min(1))]:
        ang = angles(V, F[f:f + 1])[0]
        i = int(np.argmax(ang))
        c, a, b = (int(F[f, (i + j) % 3]) for j in range(3))
        g = he.get((b, a))
        if g is None or f in done or g in done:
            continue
        d = int(next(x for x in F[g] if x != a and x != b))
        if d == c or (c, d) in he or (d, c) in he or valence[a] <= 3 or valence[b] <= 3:
            continue
        new = np.array([[a, d, c], [b, c, d]])
        n_new, n_old = face_normals(V, new), face_normals(V, F[[f, g]]).sum(0)
        if (n_new @ n_old).min() <= 0 or n_new[0] @ n_new[1] < 0.5:
            continue
        if angles(V, new).min() <= angles(V, F[[f, g]]).min():
            continue
        for row in (F[f], F[g]):
            for x, y in zip(row, np.roll(row, -1)):
                he.pop((int(x), int(y)), None)
        F[f], F[g] = new
        for h in (f, g):
            for x, y in zip(F[h], np.roll(F[h], -1)):
                he[(int(x), int(y))] = h
        valence[[a, b]] -= 1
        valence[[c, d]] += 1
        done.update((f, g))
        flips += 1
    return F, flips


def _project(Q, Vp, Fp):
    from mi_loop.mesh.sampling import closest_points

    return closest_points(Vp, Fp, Q)[1]


def _relax(V, F, verts, Vp, Fp, step: float = 0.5, iterations: int = 3):
    """Move ``verts`` toward their one-ring centroid in the tangent plane, then onto the Poisson surface.

    Moves that would flip an incident face are undone.
    """
    from scipy.sparse import coo_matrix

    n = len(V)
    i, j = F.ravel(), F[:, [1, 2, 0]].ravel()
    A = coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n)).tocsr()
    A = ((A + A.T) > 0).astype(np.float64)
    deg = np.asarray(A.sum(1)).ravel()
    for _ in range(iterations):
        fn = face_normals(V, F)
        vn = np.zeros_like(V)
        np.add.at(vn, F.ravel(), np.repeat(fn, 3, axis=0))
        vn /= np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-300)
        delta = (A[verts] @ V) / deg[verts, None] - V[verts]
        delta -= np.einsum("ij,ij->i", delta, vn[verts])[:, None] * vn[verts]
        W = V.copy()
        W[verts] = _project(V[verts] + step * delta, Vp, Fp)
        flipped = np.einsum("ij,ij->i", face_normals(W, F), fn) <= 0
        W[F[flipped].ravel()] = V[F[flipped].ravel()]
        V = W
    return V


def _collapse_short_edges(V, F, bad, Vp, Fp):
    """Collapse the shortest edge of each bad face to its midpoint (projected) where topology allows."""
    V, F = V.copy(), F.copy()
    alive = np.ones(len(F), bool)
    faces_of = [[] for _ in range(len(V))]
    for f, row in enumerate(F):
        for v in row:
            faces_of[v].append(f)
    T = V[F[bad]]
    k = np.argmin(np.linalg.norm(np.roll(T, -1, axis=1) - T, axis=2), axis=1)
    ab = np.stack([F[bad, k], F[bad, (k + 1) % 3]], 1)
    mid = _project((V[ab[:, 0]] + V[ab[:, 1]]) / 2, Vp, Fp)
    locked, collapses = np.zeros(len(V), bool), 0
    for (a, b), p in zip(ab.tolist(), mid):
        if locked[a] or locked[b] or alive.sum() <= 4:
            continue
        fa, fb = set(faces_of[a]), set(faces_of[b])
        shared = sorted(fa & fb)
        ring = lambda fs, v: {int(x) for g in fs for x in F[g] if x != v}  # noqa: E731
        opposite = ring(shared, a) - {b}
        if len(shared) != 2 or ring(fa, a) & ring(fb, b) != opposite:
            continue                                        # link condition
        if any(len(faces_of[c]) <= 3 for c in opposite):
            continue
        around = sorted((fa | fb) - set(shared))
        Fn = np.where(F[around] == b, a, F[around])
        W = V.copy()
        W[a] = p
        if (np.einsum("ij,ij->i", face_normals(W, Fn), face_normals(V, F[around])) <= 0.2).any():
            continue
        V[a], F[around] = p, Fn
        alive[shared] = False
        for g in (fa | fb):
            locked[F[g]] = True
        collapses += 1
    F = F[alive]
    used = np.unique(F)
    remap = np.full(len(V), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return V[used], remap[F], collapses
