"""Distances between a fitted surface and a target: exact point-to-triangle queries (NumPy/SciPy).

Surfaces are dense triangle meshes (for a Loop surface: the limit points of a
:func:`mi_loop.tessellate` tessellation and its ``F_tess``). Point-to-surface
distances are exact point-to-triangle distances; a :class:`scipy.spatial.cKDTree`
only prefilters candidate triangles (no approximation).

- :func:`two_sided`: mean / RMS / Hausdorff relative to the target's bounding-box
  diagonal, both directions (thesis Fig. 6.9 convention).
- :func:`nps_metrics`: the Neural Parametric Surfaces protocol (P2S, HD, NAE).
"""
from __future__ import annotations

import numpy as np

from mi_loop.errors import fail
from mi_loop.mesh.checks import check_points, check_triangles
from mi_loop.mesh.geometry import face_normals
from mi_loop.mesh.sampling import closest_points, sample_surface, surface_distances

__all__ = ["nps_metrics", "two_sided"]


def _stats(d, scale):
    d = d / scale
    return {"mean": float(d.mean()), "rms": float(np.sqrt(np.mean(d * d))), "max": float(d.max())}


def two_sided(V_fit, F_fit, target, F_target=None, n_samples: int = 100_000, seed: int = 0):
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
        d_s2p = cKDTree(target).query(S_fit)[0]
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
