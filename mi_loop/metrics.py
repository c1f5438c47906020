"""Distances between a fitted surface and a target: exact point-to-triangle queries (NumPy/SciPy).

Surfaces are dense triangle meshes (for a Loop surface: the limit points of a
:func:`mi_loop.tessellate` tessellation and its ``F_tess``). Point-to-surface
distances are exact point-to-triangle distances; a :class:`scipy.spatial.cKDTree`
only prefilters candidate triangles (no approximation).

- :func:`two_sided`: mean / RMS / Hausdorff relative to the target's bounding-box
  diagonal, both directions (thesis Fig. 6.9 convention).
- :func:`nps_metrics`: the Neural Parametric Surfaces protocol (P2S, HD, NAE).
- :func:`flipped_fraction`: area of a surface facing against its target (folds).
- :func:`self_intersections`: the triangles of a mesh that cross another of its
  triangles (pymeshlab), e.g. where a fold or two fused parts pass through each other.
- :func:`attach`, :func:`attach_points` and :func:`drift`: correspondence drift
  against a target sequence in correspondence, meshes or points (the same
  barycentric point followed over time).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mi_loop.errors import fail
from mi_loop.mesh.checks import check_points, check_triangles
from mi_loop.mesh.geometry import face_normals
from mi_loop.mesh.sampling import closest_points, sample_surface, surface_distances

__all__ = ["Attachment", "attach", "attach_points", "drift", "flipped_fraction", "nps_metrics", "self_intersections",
           "two_sided"]


def _stats(d, scale):
    d = d / scale
    return {"mean": float(d.mean()), "rms": float(np.sqrt(np.mean(d * d))), "max": float(d.max())}


def two_sided(V_fit, F_fit, target, F_target=None, n_samples: int = 100_000, seed: int = 0, *,
              exact=None):
    """Two-sided distances between a fitted surface and a target, relative to the target's bbox diagonal.

    Parameters
    ----------
    V_fit : (n, 3) float NumPy array
        Dense mesh of the fitted (limit) surface, e.g. ``limit_matrix(F, n, face_ids, uv) @ V``.
    F_fit : (m, 3) int NumPy array
        Its triangles, e.g. ``F_tess`` of :func:`mi_loop.tessellate`.
    target : (k, 3) float NumPy array
        Target points, or target mesh vertices when ``F_target`` is given.
    F_target : (l, 3) int NumPy array or None
        Target triangles; None means ``target`` is a point set.
    n_samples : int
        Area-weighted samples drawn on the fitted surface, and on a target mesh.
    seed : int
        Sampling seed.
    exact : callable, optional
        For a point set drawn from a surface known in closed form:
        ``exact(X)`` gives the distances of points ``(s, 3)`` to that
        surface, used for ``s2p`` instead of the distance to the nearest
        target point (which grows with the spacing of the points, not with
        the error of the fit). See :func:`mi_loop.datasets.torus_distance`.

    Returns
    -------
    out : dict
        ``p2s_mean/p2s_rms/p2s_max``: target points (the point set, or
        samples of the target mesh) to the fitted surface;
        ``s2p_mean/s2p_rms/s2p_max``: fitted-surface samples to the target
        surface (or to the nearest target point for a point set);
        ``mean = (p2s_mean + s2p_mean) / 2``,
        ``rms = sqrt((p2s_rms**2 + s2p_rms**2) / 2)``,
        ``hausdorff = max(p2s_max, s2p_max)``; all divided by ``diagonal``,
        the target's bounding-box diagonal (thesis Fig. 6.9). Also
        ``diagonal``, ``n_target``, ``n_fit``.

    Notes
    -----
    Distances to meshes are exact point-to-triangle distances
    (:func:`closest_points`); only the samples are random.
    """
    from scipy.spatial import cKDTree

    V_fit, F_fit = check_triangles(V_fit, F_fit, "two_sided", "fitted")
    target = check_points(target, "two_sided", "target")
    diag = float(np.linalg.norm(target.max(0) - target.min(0)))
    if not diag > 0:
        fail("two_sided", "a target with a bounding box of non-zero diagonal", "zero diagonal")
    S_fit = sample_surface(V_fit, F_fit, n_samples, seed)[0]
    if F_target is None:
        P_tgt = target
        d_s2p = cKDTree(target).query(S_fit)[0] if exact is None else np.asarray(exact(S_fit), dtype=np.float64)
    else:
        target, F_target = check_triangles(target, F_target, "two_sided", "target")
        diag = float(np.linalg.norm(np.ptp(target[np.unique(F_target)], axis=0)))
        P_tgt = sample_surface(target, F_target, n_samples, seed + 1)[0]
        d_s2p = surface_distances(target, F_target, S_fit)
    d_p2s = surface_distances(V_fit, F_fit, P_tgt)
    a, b = _stats(d_p2s, diag), _stats(d_s2p, diag)
    out = {f"p2s_{k}": v for k, v in a.items()} | {f"s2p_{k}": v for k, v in b.items()}
    out.update(mean=(a["mean"] + b["mean"]) / 2, rms=float(np.sqrt((a["rms"] ** 2 + b["rms"] ** 2) / 2)),
               hausdorff=max(a["max"], b["max"]), diagonal=diag, n_target=len(P_tgt), n_fit=len(S_fit))
    return out


def nps_metrics(mesh_fit, mesh_target, n: int = 30_000, seed: int = 0):
    """Compare two meshes with the Neural Parametric Surfaces protocol.

    Both meshes are translated by the centre of the target's bounding box and
    scaled together so that the target's largest extent is 2. ``n``
    area-weighted samples are drawn on each surface.

    Parameters
    ----------
    mesh_fit : tuple ``(V (n, 3) float, F (m, 3) int)`` of NumPy arrays
        Fitted surface (dense tessellation of the limit surface).
    mesh_target : tuple ``(V, F)``
        Target surface.
    n : int
        Samples per surface (the protocol uses 30,000).
    seed : int
        Sampling seed.

    Returns
    -------
    out : dict
        ``P2S``: mean of the two one-sided mean distances; ``HD``: max of
        the two one-sided maxima (both in normalised units; the paper prints
        them x 1e3); ``NAE``: mean over both directions of the unoriented
        angle in degrees, ``arccos |n_sample . n_closest|``, between a sample's
        face normal and the face normal at its closest point on the other
        surface; ``NAE_oriented`` the same without the absolute value; the
        one-sided ``p2s_fit_to_target``, ``p2s_target_to_fit``,
        ``hd_fit_to_target``, ``hd_target_to_fit``; ``scale`` (applied factor).

    Notes
    -----
    Unoriented NAE matches protocols that ignore orientation (open or
    inconsistently oriented outputs); ``NAE_oriented`` also penalises flips.
    """
    Vf, Ff = check_triangles(*mesh_fit, "nps_metrics", "fitted")
    Vt, Ft = check_triangles(*mesh_target, "nps_metrics", "target")
    used = Vt[np.unique(Ft)]
    lo, hi = used.min(0), used.max(0)
    if not (hi - lo).max() > 0:
        fail("nps_metrics", "a target of non-zero extent", "zero extent")
    centre, scale = (lo + hi) / 2, 2.0 / (hi - lo).max()
    Vf, Vt = (Vf - centre) * scale, (Vt - centre) * scale
    Pf, Nf, _ = sample_surface(Vf, Ff, n, seed)
    Pt, Nt, _ = sample_surface(Vt, Ft, n, seed + 1)
    d_ft, _, face_t = closest_points(Vt, Ft, Pf)
    d_tf, _, face_f = closest_points(Vf, Ff, Pt)
    cos_ft = np.einsum('ij,ij->i', Nf, face_normals(Vt, Ft)[face_t])
    cos_tf = np.einsum('ij,ij->i', Nt, face_normals(Vf, Ff)[face_f])
    ang = lambda c: np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))  # noqa: E731
    return {"P2S": float((d_ft.mean() + d_tf.mean()) / 2), "HD": float(max(d_ft.max(), d_tf.max())),
            "NAE": float((ang(np.abs(cos_ft)).mean() + ang(np.abs(cos_tf)).mean()) / 2),
            "NAE_oriented": float((ang(cos_ft).mean() + ang(cos_tf).mean()) / 2),
            "p2s_fit_to_target": float(d_ft.mean()), "p2s_target_to_fit": float(d_tf.mean()),
            "hd_fit_to_target": float(d_ft.max()), "hd_target_to_fit": float(d_tf.max()),
            "scale": float(scale), "n": int(n)}


def flipped_fraction(V_fit, F_fit, target, F_target=None, N_target=None, radius: float | None = None) -> float:
    """Share of a surface's area whose normal points against the nearest part of the target.

    A fold (the surface turned over on itself) shows as such area. Against a
    target mesh every triangle of the fitted surface is compared with the
    nearest target triangle; near the target's sharp edges the nearest face
    can be the neighbour across the edge, so a faceted target gives a small
    non-zero floor. Against oriented points (a partial scan) only triangles
    within ``radius`` of a point count as flipped or not; the rest of the
    surface (what the scan never saw) counts as not flipped, and the share is
    still of the whole area.

    Parameters
    ----------
    V_fit, F_fit : (n, 3) float and (m, 3) int NumPy arrays
        Dense mesh of the fitted surface (consistently oriented).
    target : (k, 3) float NumPy array
        Target vertices (with ``F_target``) or points (with ``N_target``).
    F_target : (l, 3) int NumPy array, optional
        Target triangles.
    N_target : (k, 3) float NumPy array, optional
        Normals of target points (without ``F_target``).
    radius : float, optional
        Largest distance from a triangle's centroid to a target point for it
        to be compared (points only; default: 3x the median nearest-neighbour
        spacing of the points).

    Returns
    -------
    float
        In [0, 1].

    Raises
    ------
    ValueError
        Neither ``F_target`` nor ``N_target``, or arrays of the wrong shape.

    Examples
    --------
    >>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    >>> F = np.array([[0, 1, 2], [1, 3, 2]])
    >>> flipped_fraction(V, F, V, F), flipped_fraction(V, F[:, ::-1], V, F)
    (0.0, 1.0)
    """
    from scipy.spatial import cKDTree

    V_fit, F_fit = check_triangles(V_fit, F_fit, "flipped_fraction", "fitted")
    n = np.cross(V_fit[F_fit[:, 1]] - V_fit[F_fit[:, 0]], V_fit[F_fit[:, 2]] - V_fit[F_fit[:, 0]])
    area = np.linalg.norm(n, axis=1)
    centroids = V_fit[F_fit].mean(1)
    if F_target is not None:
        target, F_target = check_triangles(target, F_target, "flipped_fraction", "target")
        _, _, face = closest_points(target, F_target, centroids)
        flipped = np.einsum("ij,ij->i", n, face_normals(target, F_target)[face]) < 0
    elif N_target is not None:
        target = check_points(target, "flipped_fraction", "target")
        N_target = check_points(N_target, "flipped_fraction", "target normals")
        if len(N_target) != len(target):
            fail("flipped_fraction", f"one normal per target point ({len(target)})", f"{len(N_target)} normals")
        tree = cKDTree(target)
        if radius is None:
            radius = 3.0 * float(np.median(tree.query(target, k=2)[0][:, 1]))
        d, i = tree.query(centroids)
        flipped = (d <= radius) & (np.einsum("ij,ij->i", n, N_target[i]) < 0)
    else:
        fail("flipped_fraction", "target faces F_target or target normals N_target", "neither")
    total = area.sum()
    return float(area[flipped].sum() / total) if total > 0 else 0.0


def self_intersections(V, F) -> np.ndarray:
    """Mark the triangles of a mesh that intersect another triangle of the same mesh.

    Parameters
    ----------
    V : (n, 3) float NumPy array
        Vertices.
    F : (m, 3) int NumPy array
        Triangles.

    Returns
    -------
    (m,) bool NumPy array
        True for every triangle that another triangle passes through: one
        sharing no vertex with it, or one vertex (a fan that turned through
        itself). Triangles that share an edge, that only touch, or that
        overlap in one plane are not counted.

    Notes
    -----
    MeshLab's ``compute_selection_by_self_intersections_per_face``
    (pymeshlab): a uniform-grid broad phase and exact triangle-triangle
    tests, so the cost grows with the number of triangles and of close pairs
    rather than with all pairs (timings in BENCHMARKS.md, section "No folds
    in static fits").

    Examples
    --------
    >>> V = np.array([[0., 0, 0], [2, 0, 0], [0, 2, 0], [0.5, 0.5, -1], [0.5, 0.5, 1], [1.5, 1.5, 0]])
    >>> self_intersections(V, np.array([[0, 1, 2], [3, 4, 5]])).tolist()
    [True, True]
    >>> self_intersections(V, np.array([[0, 1, 2], [1, 5, 2]])).tolist()
    [False, False]
    """
    import pymeshlab

    V, F = check_triangles(V, F, "self_intersections")
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=V, face_matrix=F.astype(np.int32)))
    ms.compute_selection_by_self_intersections_per_face()
    mesh = ms.current_mesh()
    if mesh.face_number() != len(F):     # MeshLab keeps the triangles in order; anything else would misreport
        raise RuntimeError(f"self_intersections(): MeshLab returned {mesh.face_number()} faces for {len(F)}")
    return np.asarray(mesh.face_selection_array(), dtype=bool)


@dataclass(frozen=True)
class Attachment:
    """Points attached to a target: a triangle and barycentric coordinates each (:func:`attach`, :func:`attach_points`).

    Attributes
    ----------
    face : (k,) int64 NumPy array
        Target triangle of each point.
    bary : (k, 3) float64 NumPy array
        Barycentric coordinates in it (non-negative, summing to 1).
    F : (m, 3) int64 NumPy array
        The target's triangles (shared by every frame of the sequence); for a
        point cloud (:func:`attach_points`), each point's 3 nearest cloud points.
    cloud : bool
        Attached to a point cloud: :func:`drift` measures relative to the whole cloud's diagonal.
    """

    face: np.ndarray
    bary: np.ndarray
    F: np.ndarray
    cloud: bool = False

    def points(self, V) -> np.ndarray:
        """The attached points on a mesh with the target's connectivity and vertices ``V``: ``(k, 3)``."""
        return np.einsum("kj,kjd->kd", self.bary, np.asarray(V, dtype=np.float64)[self.F[self.face]])


def attach(points, V, F) -> Attachment:
    """Attach points to their nearest points on a triangle mesh (triangle and barycentric coordinates).

    Parameters
    ----------
    points : (k, 3) float NumPy array
        Points to attach (e.g. the limit points of the control vertices at frame 0).
    V, F : (n, 3) float and (m, 3) int NumPy arrays
        The target mesh (e.g. the clean frame 0 of a sequence in correspondence).

    Returns
    -------
    Attachment
        Its :meth:`~Attachment.points` on ``V`` is the nearest points themselves.

    Examples
    --------
    >>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0]]); F = np.array([[0, 1, 2]])
    >>> a = attach(np.array([[0.25, 0.25, 1.0]]), V, F)
    >>> a.bary.round(6).tolist(), a.points(2 * V).round(6).tolist()
    ([[0.5, 0.25, 0.25]], [[0.5, 0.5, 0.0]])
    """
    V, F = check_triangles(V, F, "attach", "target")
    points = check_points(points, "attach")
    _, C, face = closest_points(V, F, points)
    return Attachment(face.astype(np.int64), _clamped_barycentric(C, *(V[F[face, k]] for k in range(3))), F)


def attach_points(points, P) -> Attachment:
    """Attach points to a point cloud in correspondence: the triangle of their 3 nearest points.

    Each point is projected on the plane of the triangle of its 3 nearest
    cloud points; its barycentric coordinates there are clamped to the
    triangle (negative ones set to 0, the rest rescaled to sum to 1). The same
    combination of the same cloud points at a later frame is where the point
    should be (:func:`drift`).

    Parameters
    ----------
    points : (k, 3) float NumPy array
        Points to attach (e.g. the limit points of the control vertices at frame 0).
    P : (N, 3) float NumPy array
        The cloud at frame 0 (point ``i`` the same material point in every frame), N >= 3.

    Returns
    -------
    Attachment
        With ``F`` the triangles of nearest points (one per attached point) and ``cloud`` True.

    Examples
    --------
    >>> P = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5]])
    >>> a = attach_points(np.array([[0.25, 0.25, 1.0]]), P)
    >>> sorted(a.F[0].tolist()), a.points(2 * P).round(6).tolist()
    ([0, 1, 2], [[0.5, 0.5, 0.0]])
    """
    from scipy.spatial import cKDTree

    points = check_points(points, "attach_points")
    P = check_points(P, "attach_points", "cloud points")
    if len(P) < 3:
        fail("attach_points", "a cloud of at least 3 points", f"{len(P)}")
    _, idx = cKDTree(P).query(points, k=3, workers=-1)
    a, b, c = (P[idx[:, j]] for j in range(3))
    n = np.cross(b - a, c - a)
    nn = np.einsum("ij,ij->i", n, n)
    t = np.where(nn > 0, np.einsum("ij,ij->i", points - a, n) / np.where(nn > 0, nn, 1.0), 0.0)
    C = points - t[:, None] * n                       # on the triangle's plane
    return Attachment(np.arange(len(points), dtype=np.int64), _clamped_barycentric(C, a, b, c),
                      idx.astype(np.int64), cloud=True)


def _clamped_barycentric(C, a, b, c) -> np.ndarray:
    """Barycentric coordinates of ``C`` in triangles ``(a, b, c)``, negatives clamped to 0, summing to 1."""
    v0, v1, v2 = b - a, c - a, C - a
    d00, d01, d11 = (np.einsum("ij,ij->i", x, y) for x, y in ((v0, v0), (v0, v1), (v1, v1)))
    d20, d21 = np.einsum("ij,ij->i", v2, v0), np.einsum("ij,ij->i", v2, v1)
    den = d00 * d11 - d01 * d01
    ok = np.abs(den) > 1e-300
    w1 = np.where(ok, (d11 * d20 - d01 * d21) / np.where(ok, den, 1.0), 0.0)
    w2 = np.where(ok, (d00 * d21 - d01 * d20) / np.where(ok, den, 1.0), 0.0)
    bary = np.clip(np.stack([1.0 - w1 - w2, w1, w2], axis=1), 0.0, None)
    return bary / bary.sum(1, keepdims=True)


def drift(points, attachment: Attachment, V) -> dict:
    """Correspondence drift: distance from each point to its attached point on a later frame.

    Parameters
    ----------
    points : (k, 3) float NumPy array
        The same points at frame ``t`` (e.g. control-vertex limit points of the fit at ``t``).
    attachment : Attachment
        Their attachment at frame 0 (:func:`attach` or :func:`attach_points`).
    V : (n, 3) float NumPy array
        Target vertices at frame ``t`` (the attachment's connectivity).

    Returns
    -------
    dict
        ``mean`` and ``p95`` of the distances relative to frame ``t``'s
        bounding-box diagonal, and ``max``.

    Examples
    --------
    >>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0]]); F = np.array([[0, 1, 2]])
    >>> a = attach(np.array([[0.0, 0.0, 0.0]]), V, F)
    >>> round(float(drift(np.array([[0.1, 0.0, 0.0]]), a, V)["mean"] * np.sqrt(2)), 6)
    0.1
    """
    points = check_points(points, "drift")
    V = check_points(V, "drift", "target vertices")
    if len(points) != len(attachment.face):
        fail("drift", f"{len(attachment.face)} points (as attached)", f"{len(points)}")
    used = V if attachment.cloud else V[np.unique(attachment.F)]
    diag = float(np.linalg.norm(used.max(0) - used.min(0)))
    d = np.linalg.norm(points - attachment.points(V), axis=1) / diag
    return {"mean": float(d.mean()), "p95": float(np.percentile(d, 95)), "max": float(d.max())}
