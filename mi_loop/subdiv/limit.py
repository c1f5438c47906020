"""Exact Loop limit evaluation at arbitrary ``(face, u, v)`` as sparse rows (NumPy/SciPy).

On the :class:`~mi_loop.subdiv.hierarchy.Hierarchy` (the control mesh refined
until every face has at most one irregular corner), regular faces are quartic
box-spline patches (with phantom points along creases and boundaries); faces
with an irregular corner use :mod:`mi_loop.subdiv.irregular`. Rows are kept
factored as ``W_L @ S_L``: ``W_L`` (padded, on the level-``L`` vertices) times
the composed subdivision matrix ``S_L``. At the control vertices the limit
points have closed-form masks (:func:`position_masks`), which
:func:`limit_matrix` takes when every sample is a face corner and
:mod:`mi_loop.subdiv.masks` builds on.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from mi_loop.errors import fail
from mi_loop.mesh.halfedge import Topology
from mi_loop.mesh.topology import sharp_topology
from mi_loop.subdiv.boxspline import PRODUCT_ROWS, box_rows
from mi_loop.subdiv.hierarchy import Hierarchy, build_hierarchy
from mi_loop.subdiv.irregular import IrregularSamples
from mi_loop.subdiv.subdivision import loop_beta
from mi_loop.subdiv.tessellation import vertex_samples

__all__ = ["check_samples", "level_rows", "limit_matrix", "padded_to_csr", "position_masks", "requested_derivatives",
           "vertex_rows"]


def level_rows(h: Hierarchy, face_ids, uv, derivatives=(None,)):
    """Return padded limit rows over the level-``L`` vertices, one pair per derivative.

    Parameters
    ----------
    h : Hierarchy
        From :func:`build_hierarchy`.
    face_ids : (k,) int64 numpy array
        Control face of every sample (checked by :func:`check_samples`).
    uv : (k, 2) float64 numpy array
        Parameters in the control faces (checked by :func:`check_samples`).
    derivatives : tuple of None, 'u', 'v'
        Which rows to return: the limit point (None) or a parametric derivative.

    Returns
    -------
    list of tuples ``(idx (k, w) int32 numpy array, W (k, w) float64 numpy array)``
        One pair per entry of ``derivatives``; row ``i`` of the limit matrix
        over level ``L`` is ``sum_j W[i, j] e_{idx[i, j]}``. The index array
        does not depend on the derivative and is the same object in every pair.

    Notes
    -----
    Every sample's box-spline rows are evaluated once, at the parameters of
    its regular patch (the level-``L`` face, or the regular child next to an
    irregular vertex), blocked so that temporaries stay in cache; phantom
    patterns and irregular configurations are then applied group by group.

    Examples
    --------
    >>> F = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])
    >>> h = build_hierarchy(F, 4)
    >>> (idx, W), = level_rows(h, np.array([0]), np.array([[0.25, 0.25]]))
    >>> idx.shape == W.shape, round(float(W.sum()), 12)
    (True, 1.0)
    """
    from mi_loop.subdiv.compose import level_params  # Numba: imported on first use

    faces, u, v, scale = level_params(h, face_ids, uv)
    ii = np.flatnonzero(h.irr_corner[faces] >= 0)
    width = max(12, int(h.irr_K[faces[ii]].max())) if len(ii) else 12
    idx = np.take(np.ascontiguousarray(h.face_P[:, :width]), faces, axis=0)
    irr = IrregularSamples(h, ii, faces[ii], u[ii], v[ii], scale[ii]) if len(ii) else None
    if irr is not None:
        u[irr.rows], v[irr.rows] = irr.cu, irr.cv
    W = box_rows(u, v, derivatives, width, scale)
    pr = np.flatnonzero(h.phantom[faces]) if h.phantom.any() else ()
    if len(pr):
        pid = h.reg_pid[faces[pr]]
        for p in np.unique(pid):
            rows_p = pr[pid == p]
            for a in range(0, len(rows_p), PRODUCT_ROWS):
                rows = rows_p[a:a + PRODUCT_ROWS]
                for Wd in W.values():
                    Wd[rows, :12] = np.take(Wd, rows, axis=0)[:, :12] @ h.Phis[p]
    if irr is not None:
        irr.apply(h, W)
    return [(idx, W[d]) for d in derivatives]


def check_samples(face_ids, uv, m, func, hole=None):
    """Check limit-sample parameters; return int64 face ids and ``uv`` snapped into the triangle.

    Parameters
    ----------
    face_ids : (k,) int array_like
        Control face of every sample, in ``[0, m)``.
    uv : (k, 2) float array_like
        Parameters with ``u >= 0``, ``v >= 0``, ``u + v <= 1`` (1e-12 slack,
        removed here).
    m : int
        Number of control faces.
    func : str
        Name of the calling public function, for the message.
    hole : (m,) bool numpy array, optional
        Faces that are holes (:attr:`~mi_loop.mesh.halfedge.Topology.hole`).

    Returns
    -------
    face_ids : (k,) int64 numpy array
    uv : (k, 2) float64 numpy array

    Raises
    ------
    ValueError
        Bad shapes or dtype, a face id out of range or on a hole, ``uv``
        outside the triangle; the first offending sample is named.

    Examples
    --------
    >>> check_samples([0, 1], [[0.5, 0.5 + 1e-13], [0.0, 0.0]], 2, "f")[1].sum(1).tolist()
    [1.0, 0.0]
    >>> check_samples([0, 2], [[0.2, 0.2], [0.2, 0.2]], 2, "f")
    Traceback (most recent call last):
    ...
    ValueError: f(): expected face ids in [0, 2), got face id 2 at sample 1
    """
    face_ids = np.asarray(face_ids)
    uv = np.asarray(uv, dtype=np.float64)
    if face_ids.ndim != 1 or not np.issubdtype(face_ids.dtype, np.integer):
        fail(func, "face_ids as a 1-D integer array", f"{face_ids.dtype} array of shape {face_ids.shape}")
    if uv.shape != (len(face_ids), 2):
        fail(func, f"uv of shape ({len(face_ids)}, 2) (one row per face id)", f"shape {uv.shape}")
    bad = np.flatnonzero((face_ids < 0) | (face_ids >= m))
    if len(bad):
        fail(func, f"face ids in [0, {m})", f"face id {face_ids[bad[0]]} at sample {bad[0]}")
    if hole is not None and hole[face_ids].any():
        bad = np.flatnonzero(hole[face_ids])
        fail(func, "samples on faces of the limit surface",
             f"face {face_ids[bad[0]]} at sample {bad[0]}, a hole under boundary='none' (a vertex of it is "
             f"on a boundary that is not an infinitely sharp crease); {int(hole.sum())} of {m} faces are holes")
    tol = 1e-12
    u, v = uv[:, 0], uv[:, 1]
    ok = u >= -tol                      # also False for NaN and -inf; u + v catches +inf
    ok &= v >= -tol
    ok &= u + v <= 1 + tol
    if not ok.all():
        bad = np.flatnonzero(~ok)
        fail(func, "uv with u >= 0, v >= 0, u + v <= 1", f"uv = {uv[bad[0]].tolist()} at sample {bad[0]}")
    uv = np.clip(uv, 0.0, 1.0)
    over = np.flatnonzero(uv[:, 0] + uv[:, 1] > 1.0)
    if len(over):
        uv[over] /= uv[over].sum(1, keepdims=True)
    return face_ids.astype(np.int64), uv


def padded_to_csr(idx, W, n_cols):
    """Return the CSR matrix of padded rows (duplicates summed, zeros dropped).

    Parameters
    ----------
    idx : (k, w) int numpy array
        Column of every entry (padding entries may point anywhere).
    W : (k, w) float64 numpy array
        Weights (zero on padding).
    n_cols : int
        Number of columns.

    Returns
    -------
    scipy.sparse.csr_matrix, shape ``(k, n_cols)``, float64

    Examples
    --------
    >>> padded_to_csr(np.array([[0, 2, 0]]), np.array([[0.25, 0.5, 0.25]]), 3).toarray().tolist()
    [[0.5, 0.0, 0.5]]
    """
    k, w = W.shape
    # Copies: sum_duplicates() sorts and compacts the arrays in place.
    M = sp.csr_matrix((W.ravel().copy(), idx.ravel().copy(), np.arange(0, k * w + 1, w)),
                      shape=(k, n_cols))
    M.sum_duplicates()
    M.eliminate_zeros()
    return M


def vertex_rows(F, n_vertices, model, derivatives, func):
    """Return the limit rows at the control vertices from the hierarchy, one matrix per derivative.

    Parameters
    ----------
    F : (m, 3) int numpy array
        Control faces; every vertex must be used by a face.
    n_vertices : int
        Number of control vertices ``n``.
    model : dict
        The crease keywords of :func:`~mi_loop.subdiv.hierarchy.build_hierarchy`
        (``creases``, ``corners``, ``boundary``, ``crease_method``).
    derivatives : tuple of None, 'u', 'v'
        The limit point (None) or a parametric derivative, in the face that
        :func:`~mi_loop.subdiv.tessellation.vertex_samples` picks for each vertex.
    func : str
        Name of the calling public function, for error messages.

    Returns
    -------
    list of scipy.sparse.csr_matrix, shape ``(n, n)``, float64
        One per entry of ``derivatives``.
    """
    from mi_loop.subdiv.compose import composed_rows  # Numba: imported on first use

    h = build_hierarchy(F, n_vertices, func=func, **model)
    face, uv = vertex_samples(h.levels[0].F, n_vertices)
    return composed_rows(h, face, uv, derivatives)


def position_masks(topo: Topology, func, model):
    """Return the limit-position masks at the control vertices: closed forms, the hierarchy only where none applies.

    Parameters
    ----------
    topo : Topology
        The control mesh's :class:`~mi_loop.mesh.halfedge.Topology`, with its crease model.
    func : str
        Name of the calling public function, for error messages.
    model : dict
        The crease keywords that built ``topo``, for :func:`vertex_rows`.

    Returns
    -------
    scipy.sparse.csr_matrix, shape ``(n, n)``, float64
        Row ``i`` gives the limit point of control vertex ``i``; sorted indices.

    Notes
    -----
    The limit point of a control vertex is the dominant left eigenvector of
    its local subdivision matrix applied to its one-ring. In closed form:

    - smooth (no sharp incident edge), valence ``k``: ``chi = 1 / (3 / (8 beta(k)) + k)``
      per neighbour, ``1 - k chi`` at the centre;
    - crease (exactly two infinitely sharp incident edges, boundary edges
      included, no vertex sharpness): ``1/6, 2/3, 1/6`` along the crease (the
      cubic B-spline's limit);
    - corner (infinite vertex sharpness, e.g. a boundary vertex of one face
      under the edge-and-corner rule, or three or more infinitely sharp
      edges): the vertex itself.

    Darts (one sharp edge) and vertices with a semi-sharp edge or semi-sharp
    vertex sharpness have no such form: their rows come from the hierarchy
    (:func:`vertex_rows`), built only if one exists.
    """
    n, F = topo.n, topo.F
    E, sharp = topo.E, topo.sharpness
    ends = np.concatenate([E[:, 0], E[:, 1]])
    other = np.concatenate([E[:, 1], E[:, 0]])
    s = np.concatenate([sharp, sharp])
    valence = np.bincount(ends, minlength=n)
    hard = np.bincount(ends, weights=np.isinf(s), minlength=n)
    vs = topo.vertex_sharpness
    semi = (np.bincount(ends, weights=np.isfinite(s) & (s > 0), minlength=n) > 0) | (np.isfinite(vs) & (vs > 0))
    corner = ~semi & (np.isinf(vs) | (hard >= 3))
    crease = ~semi & ~corner & (hard == 2)
    smooth = ~semi & ~corner & (hard == 0)
    chi = 1.0 / (3.0 / (8.0 * loop_beta(np.maximum(valence, 3))) + valence)
    rows, cols, vals = [], [], []
    on = smooth[ends]                                   # smooth: chi per neighbour, 1 - k chi at the centre
    rows += [ends[on], np.flatnonzero(smooth)]
    cols += [other[on], np.flatnonzero(smooth)]
    vals += [chi[ends[on]], (1.0 - valence * chi)[smooth]]
    on = crease[ends] & np.isinf(s)                     # crease: 1/6 per crease neighbour, 2/3 at the centre
    rows += [ends[on], np.flatnonzero(crease)]
    cols += [other[on], np.flatnonzero(crease)]
    vals += [np.full(on.sum(), 1.0 / 6.0), np.full(crease.sum(), 2.0 / 3.0)]
    rows.append(np.flatnonzero(corner))                 # corner: pinned
    cols.append(np.flatnonzero(corner))
    vals.append(np.ones(corner.sum()))
    M = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))
    rest = ~(smooth | crease | corner)                  # darts, semi-sharp
    if rest.any():
        exact = vertex_rows(F, n, model, (None,), func)[0]
        keep = sp.diags(rest.astype(np.float64))
        M = sp.diags((~rest).astype(np.float64)) @ M + keep @ exact
    M = M.tocsr()
    M.sort_indices()
    return M



def requested_derivatives(derivative, func, names=("u", "v"), have="None, 'u' or 'v'"):
    """Return whether ``derivative`` is a tuple (or list) of them, and the tuple of those asked for.

    Parameters
    ----------
    derivative : None, str, or a tuple or list of them
        As given to :func:`limit_matrix`.
    func : str
        Name of the calling public function, for error messages.
    names : tuple of str
        The derivatives that can be asked for (besides None).
    have : str
        How the message names them.

    Returns
    -------
    several : bool
    wanted : tuple

    Raises
    ------
    ValueError
        An entry not None nor in ``names``, or an empty tuple.
    """
    several = isinstance(derivative, (tuple, list))
    wanted = tuple(derivative) if several else (derivative,)
    if not wanted or any(not (d is None or (isinstance(d, str) and d in names)) for d in wanted):
        fail(func, f"derivative {have}, or a non-empty tuple of them", repr(derivative))
    return several, wanted


def _all_corners(uv) -> bool:
    """Whether ``uv`` is a non-empty (k, 2) array of face corners ``(0, 0)``, ``(1, 0)``, ``(0, 1)`` only."""
    uv = np.asarray(uv)
    if uv.ndim != 2 or uv.shape[1] != 2 or len(uv) == 0 or not np.issubdtype(uv.dtype, np.number):
        return False
    u, v = uv[:, 0], uv[:, 1]
    return bool((((u == 0) | (u == 1)) & ((v == 0) | (v == 1)) & (u + v <= 1)).all())


def limit_matrix(F, n_vertices, face_ids, uv, creases=None, derivative=None, *, corners=None,
                 boundary="edge_and_corner", crease_method="uniform"):
    """Return the sparse matrix of exact limit points (or derivatives) at ``(face, u, v)``.

    Parameters
    ----------
    F : (m, 3) int numpy array
        Control faces (manifold, consistently oriented; boundaries allowed).
    n_vertices : int
        Number of control vertices ``n``.
    face_ids : (k,) int numpy array
        Control face of every sample.
    uv : (k, 2) float numpy array
        Parameters, ``u, v >= 0``, ``u + v <= 1``; the control-face point
        ``(1-u-v) V[F[f,0]] + u V[F[f,1]] + v V[F[f,2]]`` maps to the limit point.
    creases : None, (c, 2) int numpy array, or tuple ``(E, sharpness)``
        See :func:`mi_loop.subdivision_matrix`.
    derivative : None, 'u', 'v', or a tuple of them
        Limit point, or its parametric derivative. A tuple, e.g.
        ``(None, 'u', 'v')``, returns one matrix per entry, built in one pass
        (one hierarchy, one composition): about a third of the time of
        separate calls.
    corners, boundary, crease_method : optional
        The rest of OpenSubdiv's crease model, see :func:`mi_loop.subdivision_matrix`.

    Returns
    -------
    scipy.sparse.csr_matrix, shape ``(k, n)``, float64, or a tuple of them
        ``W @ V`` gives the ``(k, 3)`` limit points (derivatives). Sorted
        indices, no explicit zeros.

    Raises
    ------
    ValueError
        Invalid mesh, crease model or samples, a sample on a hole (boundary
        ``'none'``), or an unknown or empty ``derivative``; the message names the
        offending element. Two faces on the same three
        vertices (a closed two-triangle component) are refused, see
        :func:`~mi_loop.mesh.topology.validate_faces`.

    Notes
    -----
    Exact everywhere: box splines on regular patches (with phantom points on
    creases and boundaries), powers of the local subdivision matrix next to
    irregular vertices (Stam 1998, without eigenvectors), the limit mask at the
    vertex itself. At an irregular vertex the parametric derivatives vanish or
    diverge; there the two derivative rows are orthonormal rows spanning the
    limit tangent plane, oriented so that ``cross(du, dv)`` is the exact limit
    normal.

    Examples
    --------
    >>> import numpy as np, mi_loop
    >>> F = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])
    >>> W = mi_loop.limit_matrix(F, 4, np.array([0]), np.array([[0.25, 0.25]]))
    >>> W.shape, round(float(W.sum()), 12)
    ((1, 4), 1.0)
    >>> P, Du, Dv = mi_loop.limit_matrix(F, 4, np.array([0]), np.array([[0.25, 0.25]]), derivative=(None, "u", "v"))
    >>> bool(abs(P - W).max() == 0), Du.shape
    (True, (1, 4))
    """
    from mi_loop.subdiv.compose import composed_rows  # Numba: imported on first use

    several, wanted = requested_derivatives(derivative, "limit_matrix")
    model = dict(creases=creases, corners=corners, boundary=boundary, crease_method=crease_method)
    if wanted == (None,) and _all_corners(uv):   # the vertex masks, no hierarchy
        topo = sharp_topology(F, n_vertices, "limit_matrix", **model)
        face_ids, uv = check_samples(face_ids, uv, len(topo.F), "limit_matrix", topo.hole)
        corner = np.where(uv[:, 0] == 1, 1, np.where(uv[:, 1] == 1, 2, 0))
        M = position_masks(topo, "limit_matrix", model)[topo.F[face_ids, corner]]
        return (M,) if several else M
    h = build_hierarchy(F, n_vertices, func="limit_matrix", **model)
    face_ids, uv = check_samples(face_ids, uv, len(h.levels[0].F), "limit_matrix", h.levels[0].hole)
    matrices = composed_rows(h, face_ids, uv, wanted)
    return tuple(matrices) if several else matrices[0]
