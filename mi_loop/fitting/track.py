"""Track a frame with an embedded deformation graph: the coarse, material-preserving stage of a frame's solve.

A frame of a sequence moves the body far more than it changes its shape. The
control mesh is therefore first carried to the frame by a few hundred rigid
motions (Sumner et al. 2007, "Embedded deformation for shape manipulation"):
nodes ``g_j`` on the control mesh, each with a rotation ``R_j`` and a
translation ``t_j``, move a control point ``v_i`` to

    v_i' = sum_j w_ij (R_j (v_i - g_j) + g_j + t_j),

``w_ij`` the weights of its ``k`` geodesically nearest nodes. The motions are
found by Gauss-Newton (non-rigid ICP, as Li et al. 2009) on

    E = mean_s rho_s [ (n_c . (q_s - c_s))^2 + point (q_s - c_s)^2 ]
        + stiffness mean_(j,l) |R_j (g_l - g_j) + g_j + t_j - (g_l + t_l)|^2,

``q_s`` the limit samples of the deformed control mesh, ``c_s`` (normal
``n_c``) their nearest frame point where it faces the same way and lies
within the trimmed distance, ``(j, l)`` the node pairs that share a control
point. With photos, ``rays`` add ``ray mean_r |(I - d_r d_r^T)(q_r - o_r)|^2``: a
sample seen at frame ``t-1`` must lie on the camera ray (origin ``o_r``, direction
``d_r``) through the pixel the optical flow carried it to
(:func:`mi_loop.fitting.flow.sample_rays`), which says where the material went
where the points only say where the surface is. Each step re-linearises the
rotations (``R_j <- exp([w_j]) R_j``) and re-finds the correspondences; the stiffness is lowered from ``stiff[0]`` to
``stiff[1]`` over the steps (coarse to fine). A rigid motion of a limb costs no
stiffness, a bulge or a slide of the surface against its neighbours does:
what the frame's data do not ask for, the graph does not invent. The tracked
control points are the warm start (and the ARAP rest) of the frame's fine
solve (:func:`mi_loop.fitting.sequence.fit_frame`). Host NumPy/SciPy only.
"""
from __future__ import annotations

import numpy as np

__all__ = ["DeformationGraph", "anchor_weights", "edge_residuals", "in_silhouettes", "limit_samples", "track"]


def _skew(a):
    """``(k, 3, 3)`` cross-product matrices of ``(k, 3)`` vectors: ``[a]_x b = a x b``."""
    S = np.zeros(a.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2], S[..., 1, 2] = -a[..., 2], a[..., 1], -a[..., 0]
    S[..., 1, 0], S[..., 2, 0], S[..., 2, 1] = a[..., 2], -a[..., 1], a[..., 0]
    return S


def _exp(w):
    """Rotation matrices ``exp([w]_x)`` of ``(k, 3)`` rotation vectors (Rodrigues)."""
    theta = np.linalg.norm(w, axis=1)
    small = theta < 1e-12
    safe = np.where(small, 1.0, theta)
    K = _skew(w / safe[:, None])
    s, c = np.where(small, 0.0, np.sin(theta)), np.where(small, 1.0, np.cos(theta))
    return np.eye(3) + s[:, None, None] * K + (1.0 - c)[:, None, None] * (K @ K)


class DeformationGraph:
    """Nodes on a control mesh, each control point's node weights, and the node pairs (module docstring).

    Parameters
    ----------
    V : (n, 3) float array-like
        Control points (the shape the geodesic distances are measured on).
    F : (m, 3) int array-like
        Control faces.
    spacing : int
        About one node per ``spacing`` control points (farthest-point sampling
        in geodesic distance, from the point farthest from the centroid).
    k : int
        Nodes per control point.

    Attributes
    ----------
    nodes : (g,) int NumPy array
        The control points that are nodes.
    neighbours : (n, k) int NumPy array
        Each control point's ``k`` nearest nodes (indices into ``nodes``).
    weights : (n, k) float NumPy array
        Their weights, ``(1 - d / d_(k+1))^2`` normalised to sum 1.
    edges : (e, 2) int NumPy array
        Ordered node pairs ``(j, l)`` that share a control point (both directions).

    Examples
    --------
    >>> from mi_loop.datasets import icosphere
    >>> V, F = icosphere(3)
    >>> g = DeformationGraph(V, F, spacing=10)
    >>> len(g.nodes), g.neighbours.shape, bool(np.allclose(g.weights.sum(axis=1), 1.0))
    (64, (642, 4), True)
    """

    def __init__(self, V, F, spacing: int = 10, k: int = 4):
        import scipy.sparse as sp
        from scipy.sparse.csgraph import dijkstra

        from mi_loop.mesh.geometry import edges

        V = np.asarray(V, dtype=np.float64)
        n = len(V)
        E = edges(F)
        length = np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)
        G = sp.coo_matrix((length, (E[:, 0], E[:, 1])), shape=(n, n)).tocsr()
        count = max(k + 1, int(round(n / spacing)))
        nodes = [int(np.argmax(np.linalg.norm(V - V.mean(axis=0), axis=1)))]
        far = dijkstra(G, directed=False, indices=nodes[0])
        while len(nodes) < count:
            nodes.append(int(np.argmax(far)))
            far = np.minimum(far, dijkstra(G, directed=False, indices=nodes[-1]))
        D = dijkstra(G, directed=False, indices=nodes).T                 # (n, g)
        D = np.where(np.isfinite(D), D, 1e300)
        order = np.argsort(D, axis=1, kind="stable")[:, :k + 1]
        d = np.take_along_axis(D, order, axis=1)
        w = np.clip(1.0 - d[:, :k] / np.maximum(d[:, k:], 1e-300), 0.0, None) ** 2
        w[w.sum(axis=1) == 0, 0] = 1.0                                 # a point on a node: the node alone
        self.nodes, self.neighbours = np.asarray(nodes, dtype=np.int64), order[:, :k]
        self.weights = w / w.sum(axis=1, keepdims=True)
        pairs = np.concatenate([self.neighbours[:, [a, b]] for a in range(k) for b in range(k) if a != b])
        self.edges = np.unique(pairs, axis=0)

    def deform(self, V, R, t):
        """Control points ``V`` moved by the node motions ``R (g, 3, 3)``, ``t (g, 3)`` (nodes at ``V[nodes]``)."""
        g = V[self.nodes]
        d = V[:, None, :] - g[self.neighbours]                          # (n, k, 3)
        moved = np.einsum("nkab,nkb->nka", R[self.neighbours], d) + g[self.neighbours] + t[self.neighbours]
        return np.einsum("nk,nka->na", self.weights, moved)


def _jacobian(graph: DeformationGraph, V, R):
    """``d V' / d (w, t)``: sparse ``(3n, 6g)``, rotation increments ``w_j`` first, then ``t_j``, per node."""
    import scipy.sparse as sp

    n, k = graph.neighbours.shape
    d = V[:, None, :] - V[graph.nodes][graph.neighbours]
    Rd = np.einsum("nkab,nkb->nka", R[graph.neighbours], d)
    block = np.concatenate([-_skew(Rd), np.broadcast_to(np.eye(3), (n, k, 3, 3))], axis=3)   # (n, k, 3, 6)
    block *= graph.weights[:, :, None, None]
    rows = np.broadcast_to((3 * np.arange(n))[:, None, None, None] + np.arange(3)[:, None], (n, k, 3, 6))
    cols = np.broadcast_to(6 * graph.neighbours[:, :, None, None] + np.arange(6), (n, k, 3, 6))
    return sp.csr_matrix((block.ravel(), (rows.ravel(), cols.ravel())), shape=(3 * n, 6 * len(graph.nodes)))


def track(graph: DeformationGraph, V, matrices, points, normals, tree=None, *, steps: int = 12,
          stiff=(1.0, 0.1), point: float = 0.1, trim: float = 3.0, damping: float = 1e-4,
          rays=None, ray: float = 1.0):
    """Carry control points ``V`` to a frame's oriented points by the graph's node motions (module docstring).

    Parameters
    ----------
    graph : DeformationGraph
    V : (n, 3) float array-like
        Control points (the previous frame's fit); the nodes sit at ``V[graph.nodes]``.
    matrices : (P, Du, Dv) scipy.sparse matrices
        ``(k, n)`` limit positions and derivatives of the samples (:func:`mi_loop.limit_matrix`).
    points, normals : (N, 3) float NumPy arrays
        The frame's points and unit normals.
    tree : scipy.spatial.cKDTree, optional
        Of ``points``.
    steps : int
        Gauss-Newton steps.
    stiff : (float, float)
        Stiffness at the first and at the last step (geometric in between).
    point : float
        Weight of the point-to-point part of a correspondence against its point-to-plane part.
    trim : float
        Correspondences farther than ``trim`` times the median distance are dropped.
    damping : float
        Levenberg damping, relative to the mean diagonal of the normal matrix.
    rays : (sample, origin, direction) or None
        Material points seen in photos: ``(r,)`` int sample rows, and the ``(r, 3)`` origins and unit
        directions of the camera rays they must lie on (:func:`~mi_loop.fitting.flow.flow_rays`: where the
        optical flow carried them). Each adds ``ray / r |(I - d d^T)(q_s - o)|^2`` to the data term;
        rays farther than ``trim`` times their median distance are dropped, step by step.
    ray : float
        Weight of the rays against the frame's points.

    Returns
    -------
    V : (n, 3) float64 NumPy array
        The tracked control points.
    info : dict
        ``residual`` (RMS point-to-plane distance of the kept correspondences, per step),
        ``kept`` (their share of the samples, per step), ``rays`` (the share of the rays kept, per
        step), ``held`` ((k,) bool: the samples whose correspondence counts at the returned control
        points; :func:`anchor_weights`), ``pinned`` ((k,) bool: the samples whose ray counts there) and
        the nodes' motions ``R`` ((g, 3, 3)) and ``t`` ((g, 3)).
    """
    import scipy.linalg
    import scipy.sparse as sp
    from scipy.spatial import cKDTree

    V = np.asarray(V, dtype=np.float64)
    points, normals = np.asarray(points, dtype=np.float64), np.asarray(normals, dtype=np.float64)
    tree = tree if tree is not None else cKDTree(points)
    M = matrices[0]
    g = len(graph.nodes)
    M3 = sp.kron(M, sp.identity(3), format="csr")
    gnodes = V[graph.nodes]
    a, b = graph.edges[:, 0], graph.edges[:, 1]
    R, t = np.broadcast_to(np.eye(3), (g, 3, 3)).copy(), np.zeros((g, 3))
    # regulariser rows: r_jl = R_j (g_l - g_j) + g_j + t_j - g_l - t_l, linear in (w_j, t_j, t_l)
    e = len(a)
    info = {"residual": [], "kept": [], "rays": []}
    for step in range(steps):
        s = stiff[0] * (stiff[1] / stiff[0]) ** (step / max(steps - 1, 1))
        X = graph.deform(V, R, t)
        Q, idx, ok = _correspondences(matrices, X, tree, normals, trim)
        keep = np.flatnonzero(ok)
        C, Nc = points[idx[keep]], normals[idx[keep]]
        G = _jacobian(graph, V, R)                                                       # (3n, 6g)
        J = M3[np.ravel(3 * keep[:, None] + np.arange(3))] @ G                           # (3 kept, 6g)
        r = (Q[keep] - C)                                                                # (kept, 3)
        # point-to-plane rows: n_c^T J_s; point-to-point rows: sqrt(point) J_s
        Jp = _dots(Nc) @ J
        rp = np.sum(Nc * r, axis=1)
        wfit = 1.0 / max(len(keep), 1)
        A = wfit * ((Jp.T @ Jp) + point * (J.T @ J)).toarray()
        rhs = -wfit * (Jp.T @ rp + point * (J.T @ r.ravel()))
        if rays is not None and len(rays[0]):
            Ar, br, share = _ray_rows(M3, G, Q, rays, trim)
            A += ray * Ar
            rhs -= ray * br
            info["rays"].append(share)
        # regulariser
        Rg, rr = edge_residuals(gnodes, graph.edges, R, t)
        rows = np.arange(3 * e).reshape(e, 3)
        Jr_w = -_skew(Rg)                                                                # d/dw_a
        ri = np.concatenate([np.repeat(rows, 3, axis=1).ravel(), rows.ravel(), rows.ravel()])
        ci = np.concatenate([(6 * a[:, None, None] + np.arange(3)[None, None, :]).repeat(3, axis=1).ravel(),
                             (6 * a[:, None] + 3 + np.arange(3)).ravel(), (6 * b[:, None] + 3 + np.arange(3)).ravel()])
        vi = np.concatenate([Jr_w.ravel(), np.ones(3 * e), -np.ones(3 * e)])
        Jr = sp.csr_matrix((vi, (ri, ci)), shape=(3 * e, 6 * g))
        wreg = s / e
        A += wreg * (Jr.T @ Jr).toarray()
        rhs -= wreg * (Jr.T @ rr.ravel())
        A[np.diag_indices_from(A)] += damping * np.mean(np.diag(A))
        delta = scipy.linalg.solve(A, rhs, assume_a="pos").reshape(g, 6)
        R = _exp(delta[:, :3]) @ R
        t = t + delta[:, 3:]
        info["residual"].append(float(np.sqrt(np.mean(rp ** 2))) if len(rp) else float("nan"))
        info["kept"].append(len(keep) / len(Q))
    X = graph.deform(V, R, t)
    Q, _, info["held"] = _correspondences(matrices, X, tree, normals, trim)
    info["pinned"] = np.zeros(len(Q), dtype=bool)
    if rays is not None and len(rays[0]):
        info["pinned"][rays[0][_ray_offsets(Q, rays, trim)[1]]] = True
    info["R"], info["t"] = R, t
    return X, info


def edge_residuals(nodes, edges, R, t):
    """The graph regulariser's residuals ``r_jl = R_j (g_l - g_j) + g_j + t_j - g_l - t_l`` (:func:`track`).

    Parameters
    ----------
    nodes : (g, 3) float NumPy array
        Node positions ``g_j``.
    edges : (e, 2) int NumPy array
        Node pairs ``(j, l)``.
    R, t : (g, 3, 3) and (g, 3) float NumPy arrays
        Node rotations and translations.

    Returns
    -------
    Rg, r : (e, 3) float NumPy arrays
        ``R_j (g_l - g_j)`` and ``r_jl``.
    """
    a, b = edges[:, 0], edges[:, 1]
    Rg = np.einsum("eab,eb->ea", R[a], nodes[b] - nodes[a])
    return Rg, Rg + nodes[a] + t[a] - nodes[b] - t[b]


def _dots(U):
    """The sparse ``(k, 3k)`` matrix taking stacked 3-vectors ``y`` to the dot products ``U_i . y_i``."""
    import scipy.sparse as sp

    k = len(U)
    return sp.csr_matrix((U.ravel(), (np.repeat(np.arange(k), 3), np.arange(3 * k))), shape=(k, 3 * k))


def _ray_rows(M3, G, Q, rays, trim: float):
    """The rays' normal matrix and gradient, ``(A, b, kept share)``, each over the kept rays' count (:func:`track`).

    ``M3 @ G`` maps the node increments to the samples' coordinates, ``Q`` holds the samples. With
    the projector ``P = I - d d^T`` (``P^T P = P``) a ray's block of the normal matrix is
    ``J^T J - (d^T J)^T (d^T J)``, and its gradient ``J^T P (q - o)``.
    """
    sample, origin, direction = rays
    r, keep = _ray_offsets(Q, rays, trim)
    J = M3[np.ravel(3 * sample[keep, None] + np.arange(3))] @ G
    Jd = _dots(direction[keep]) @ J
    w = 1.0 / max(len(keep), 1)
    return w * (J.T @ J - Jd.T @ Jd).toarray(), w * (J.T @ r[keep].ravel()), len(keep) / len(sample)


def _ray_offsets(Q, rays, trim: float):
    """``(r, keep)``: each ray's sample's offset from it, ``(I - d d^T)(q - o)``, and the rays that count
    (offset within ``trim`` times the median)."""
    sample, origin, direction = rays
    r = Q[sample] - origin
    r -= np.sum(r * direction, axis=1, keepdims=True) * direction                   # P (q - o)
    dist = np.linalg.norm(r, axis=1)
    return r, np.flatnonzero(dist <= trim * np.median(dist) + 1e-12)


def _correspondences(matrices, X, tree, normals, trim: float):
    """``(Q, idx, ok)``: the limit samples of ``X``, their nearest frame points, and which correspondences count.

    A correspondence counts where the point's normal is within 60 degrees of the
    sample's limit normal and the distance within ``trim`` times the median of those.
    """
    Q, Nq = limit_samples(matrices, X)
    dist, idx = tree.query(Q, workers=-1)
    ok = np.sum(normals[idx] * Nq, axis=1) > 0.5
    if ok.any():
        ok &= dist <= trim * np.median(dist[ok]) + 1e-12
    return Q, idx, ok


def limit_samples(matrices, X):
    """``(Q, N)``: the limit samples of control points ``X`` and their unit normals, ``(k, 3)`` each.

    Parameters
    ----------
    matrices : (P, Du, Dv) scipy.sparse matrices
        ``(k, n)`` limit positions and derivatives of the samples (:func:`mi_loop.limit_matrix`).
    X : (n, 3) float NumPy array
        Control points.
    """
    M, Mu, Mv = matrices
    N = np.cross(Mu @ X, Mv @ X)
    return M @ X, N / np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-300)


def anchor_weights(M, held, lower: float = 0.5, upper: float = 0.9):
    """How far to trust each tracked control point: from the share of its limit support that found the frame's data.

    The share of point ``i`` is ``h_i = sum_s |M_si| held_s / sum_s |M_si|``. A
    point whose support mostly found no data (a limb that moved farther than
    the correspondences reach) was carried by its neighbours' motions alone,
    and is often wrong by more than a control edge; where the support found
    the data, the tracked point is within a fraction of an edge of the fit.

    Parameters
    ----------
    M : (k, n) scipy.sparse matrix
        Limit positions of the samples (:func:`mi_loop.limit_matrix`).
    held : (k,) bool array-like
        Samples whose correspondence counted at the tracked state (:func:`track`'s ``info["held"]``).
    lower, upper : float
        Weight 0 for ``h_i <= lower``, 1 for ``h_i >= upper``, linear in between.

    Returns
    -------
    (n,) float NumPy array
        In [0, 1]; 0 for a point that supports no sample.

    Examples
    --------
    >>> import scipy.sparse as sp
    >>> M = sp.csr_matrix(np.array([[0.5, 0.5, 0.0], [0.0, 0.25, 0.75]]))
    >>> np.round(anchor_weights(M, [True, False]), 4).tolist()       # shares 1, 2/3, 0
    [1.0, 0.4167, 0.0]
    """
    W = abs(M).tocsc()
    total = np.asarray(W.sum(axis=0)).ravel()
    covered = W.T @ np.asarray(held, dtype=np.float64)
    share = np.divide(covered, total, out=np.zeros_like(total), where=total > 0)
    return np.clip((share - lower) / (upper - lower), 0.0, 1.0)


def pinned_hold(M, pinned, factor: float) -> np.ndarray:
    """How much harder to hold each control point where photos pinned its limit support: ``1 + (factor - 1) r``.

    ``r_i = sum_s |M_si| pinned_s / sum_s |M_si|`` is the share of point ``i``'s
    support whose optical-flow ray counted at the coarse stage's end (:func:`track`'s
    ``pinned``): there the stage followed the material, not only the surface.

    Parameters
    ----------
    M : (k, n) scipy.sparse matrix
        Limit positions of the samples (:func:`mi_loop.limit_matrix`).
    pinned : (k,) bool array-like
        Samples whose ray counts.
    factor : float
        The hold of a point whose whole support is pinned, relative to one with none.

    Returns
    -------
    (n,) float NumPy array

    Examples
    --------
    >>> import scipy.sparse as sp
    >>> M = sp.csr_matrix(np.array([[0.5, 0.5, 0.0], [0.0, 0.25, 0.75]]))
    >>> np.round(pinned_hold(M, [True, False], 10.0), 4).tolist()       # shares 1, 2/3, 0
    [10.0, 7.0, 1.0]
    """
    return 1.0 + (float(factor) - 1.0) * anchor_weights(M, pinned, 0.0, 1.0)


def in_silhouettes(views, points, margin: int = 2) -> np.ndarray:
    """Which points project inside the mask of every photo that sees them: where a tracked surface can be.

    Depth from one side cannot tell a part it does not see from a part the coarse
    stage lost (both find no data); the photos' silhouettes can: a part carried
    beside the body falls outside some mask. With :func:`anchor_weights` this
    says how far to trust the tracked control points of a partial frame.

    Parameters
    ----------
    views : list of mi_loop.io.views.View
        The frame's photos.
    points : (k, 3) float NumPy array
        Points in the photos' world (the tracked limit samples).
    margin : int
        Pixels by which each mask is grown first (soft or slightly wrong masks).

    Returns
    -------
    (k,) bool NumPy array
        False where a photo sees the point outside its grown mask.
    """
    from mi_loop.fitting.hull import in_mask

    points = np.asarray(points, dtype=np.float64)
    ok = np.ones(len(points), dtype=bool)
    for view in views:
        seen, fore = in_mask(view, points, margin=margin)
        ok[np.flatnonzero(seen)[~fore]] = False
    return ok
