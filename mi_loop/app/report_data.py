"""What a job's ``report.html`` shows, computed from its results (NumPy, no file I/O).

Distances from the viewer's limit points to the data, crease curves on the
limit surface, camera frusta, a subsample of the data points, the tables;
:func:`fit_page`, :func:`images_page` and :func:`sequence_report` assemble them into
the pages of :mod:`mi_loop.app.html_report` for ``fit``, ``fit-images`` and ``fit-sequence``.
"""
from __future__ import annotations

import numpy as np

from mi_loop.app import html_report
from mi_loop.errors import fail
from mi_loop.io.files import png_bytes

__all__ = ["DATA_POINTS", "NEIGHBOURS", "crease_curves", "fit_page", "frustum_segments", "images_page",
           "sequence_report", "subsample", "vertex_distances"]

#: Data points drawn in the 3D view at most (a random subsample of larger data).
DATA_POINTS = 5000
#: Data points around each limit point for :func:`vertex_distances`' local mean surface.
NEIGHBOURS = 16
_CORNER_UV = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])


def vertex_distances(V, target, N=None, k: int = NEIGHBOURS) -> np.ndarray:
    """Distance of each point to the data, relative to the data's bounding-box diagonal.

    Parameters
    ----------
    V : (v, 3) float NumPy array
        Points (of the limit surface).
    target : tuple
        ``('mesh', V_t, F_t)``: the exact distance to the mesh's surface;
        ``('points', P, N_P)``: with ``N``, the distance to the data's local
        mean surface (below), else to the nearest data point.
    N : (v, 3) float NumPy array, optional
        Unit normals at ``V`` (the limit normals).
    k : int
        Data points around each point for the local mean surface.

    Returns
    -------
    (v,) float64 NumPy array
        Divided by the diagonal of the data's bounding box (of the mesh's used vertices),
        as in :func:`mi_loop.metrics.two_sided`.

    Notes
    -----
    The distance to the nearest of noisy points is at least their noise and
    grows with their spacing, whatever the fit; the median over the ``k``
    nearest data points of their offsets along the normal at ``V``,
    ``|median_j (V - P_j) . N|``, is the distance to the plane through their
    middle, which outliers and noise barely move.

    Examples
    --------
    >>> P = np.array([[0.0, 0, 0], [3, 4, 0]])
    >>> vertex_distances(np.array([[0.0, 0, 1]]), ("points", P, None)).tolist()
    [0.2]
    >>> P = np.array([[x, y, 0.01 * (-1) ** (x + y)] for x in range(5) for y in range(5)], float)
    >>> d = vertex_distances(np.array([[2.0, 2, 0.5]]), ("points", P, None), N=np.array([[0.0, 0, 1]]), k=9)
    >>> round(float(d[0] * np.linalg.norm(np.ptp(P, axis=0))), 6)
    0.49
    """
    from scipy.spatial import cKDTree

    from mi_loop.mesh.sampling import surface_distances

    kind, A, B = target
    V = np.asarray(V, dtype=np.float64)
    if kind == "points":
        diag = float(np.linalg.norm(np.ptp(A, axis=0)))
        if N is None:
            return cKDTree(A).query(V)[0] / diag
        _, nearest = cKDTree(A).query(V, k=min(k, len(A)))
        nearest = nearest.reshape(len(V), -1)
        offsets = np.einsum("vkc,vc->vk", V[:, None, :] - A[nearest], np.asarray(N, dtype=np.float64))
        return np.abs(np.median(offsets, axis=1)) / diag
    diag = float(np.linalg.norm(np.ptp(A[np.unique(B)], axis=0)))
    return surface_distances(A, B, V) / diag


def crease_curves(V, F, creases, level: int) -> np.ndarray:
    """Points along each crease edge's curve on the limit surface (exact limit points).

    Parameters
    ----------
    V : (n, 3) float NumPy array
        Control points.
    F : (m, 3) int NumPy array
        Control faces.
    creases : (c, 2) int NumPy array
        Crease edges of the control mesh (infinitely sharp).
    level : int
        ``2**level`` segments per edge, as many as the tessellation of that level has along it.

    Returns
    -------
    (c, 2**level + 1, 3) float64 NumPy array

    Raises
    ------
    ValueError
        A crease that is not an edge of ``F``; the message names its index.
    """
    from mi_loop.subdiv.limit import limit_matrix

    creases = np.asarray(creases, dtype=np.int64).reshape(-1, 2)
    where = {}
    for f, face in enumerate(np.asarray(F)):
        for c in range(3):
            where[(int(face[c]), int(face[(c + 1) % 3]))] = (f, c, (c + 1) % 3)
    t = np.linspace(0.0, 1.0, 2 ** level + 1)[:, None]
    face_ids, uv = [], []
    for i, (a, b) in enumerate(creases.tolist()):
        hit = where.get((a, b)) or where.get((b, a))
        if hit is None:
            fail("crease_curves", "crease edges of the control faces", f"({a}, {b}) at crease {i}")
        f, ca, cb = hit if (a, b) in where else (hit[0], hit[2], hit[1])
        face_ids.append(np.full(len(t), f))
        uv.append((1 - t) * _CORNER_UV[ca] + t * _CORNER_UV[cb])
    if not face_ids:
        return np.zeros((0, len(t), 3))
    W = limit_matrix(F, len(V), np.concatenate(face_ids), np.concatenate(uv), creases=creases)
    return (W @ np.asarray(V, dtype=np.float64)).reshape(len(creases), len(t), 3)


def frustum_segments(cameras, depth: float) -> np.ndarray:
    """Line segments of pinhole cameras' frusta: apex to the image corners at ``depth``, the image's edges.

    Parameters
    ----------
    cameras : list of mi_loop.io.Camera
        NeRF/OpenGL convention (looking down -Z of ``c2w``).
    depth : float
        Distance of the drawn image plane from each camera's centre.

    Returns
    -------
    (8 len(cameras), 2, 3) float64 NumPy array
        Four edges from the apex, four around the image, per camera.

    Examples
    --------
    >>> from mi_loop.io import Camera
    >>> cam = Camera(np.eye(4), 10.0, 10.0, 5.0, 5.0, 10, 10)
    >>> s = frustum_segments([cam], 2.0)
    >>> s.shape, s[0].tolist()
    ((8, 2, 3), [[0.0, 0.0, 0.0], [-1.0, 1.0, -2.0]])
    """
    out = []
    for cam in cameras:
        px = np.array([[0, 0], [cam.width, 0], [cam.width, cam.height], [0, cam.height]], dtype=np.float64)
        local = np.stack([(px[:, 0] - cam.cx) / cam.fx, -(px[:, 1] - cam.cy) / cam.fy, -np.ones(4)], 1) * depth
        corners = local @ cam.c2w[:3, :3].T + cam.c2w[:3, 3]
        apex = cam.c2w[:3, 3]
        out += [[apex, c] for c in corners] + [[corners[i], corners[(i + 1) % 4]] for i in range(4)]
    return np.array(out, dtype=np.float64).reshape(-1, 2, 3)


def subsample(P, k: int = DATA_POINTS, seed: int = 0) -> np.ndarray:
    """At most ``k`` of the points, chosen at random without replacement (all of them when fewer).

    Parameters
    ----------
    P : (p, 3) float NumPy array
    k : int
    seed : int

    Returns
    -------
    (min(p, k), 3) NumPy array
        In their original order.
    """
    P = np.asarray(P)
    if len(P) <= k:
        return P
    return P[np.sort(np.random.default_rng(seed).choice(len(P), k, replace=False))]


def _fit_tables(report: dict) -> dict:
    tables = {"distance to the data (relative to its bounding-box diagonal)": report["metrics"]}
    if "metrics_clean" in report:
        tables["distance to the clean torus (relative to its bounding-box diagonal)"] = report["metrics_clean"]
    params = report["params"]
    tables["fit"] = {"control vertices": params.get("n_vertices", ""), "control faces": params.get("n_faces", ""),
                     "iterations": params.get("iterations_run", ""), "converged": report["converged"],
                     "ARAP weight": params.get("alpha", ""), "seconds": report["timings_s"].get("total", "")}
    return tables


def fit_page(result, view, level: int, target, report: dict, loss, clean=None) -> str:
    """``report.html`` of ``mi-loop fit``.

    Parameters
    ----------
    result : mi_loop.fitting.static.FitResult
        The fit: control mesh ``V``, ``F`` and ``creases``.
    view : tuple ``(V (k, 3), F (m, 3), N (k, 3))``
        The viewer's limit tessellation.
    level : int
        Its level (the crease curves get as many segments per edge).
    target : tuple
        ``('points', P, N)`` or ``('mesh', V, F)``: the data.
    report : dict
        The job's ``report.json``.
    loss : (h, w, 3) uint8 NumPy array
        The loss plot.
    clean : tuple ``(name, distance)``, optional
        A surface known in closed form (the demo's clean torus) and ``distance(X)``, the distances of
        points ``(v, 3)`` to it relative to its bounding-box diagonal: a second colouring.

    Returns
    -------
    str
    """
    V, F, N = view[:3]
    creases = None
    if result.creases is not None and len(result.creases):
        creases = crease_curves(result.V, result.F, result.creases, level)
    data = target[1] if target[0] == "points" else target[1][np.unique(target[2])]
    distances = {"the data": vertex_distances(V, target, N)}
    if clean is not None:
        distances[clean[0]] = clean[1](V)
    return html_report.static_page(
        "mi-loop fit", V, F, N, subtitle=f"{report['input']}: {len(result.V)} control vertices, viewer level {level}",
        distances=distances, points=subsample(data), cage=(result.V, result.F),
        creases=creases, tables=_fit_tables(report), loss_png=png_bytes(loss))


def images_page(result, view, views, evaluation: dict, shown, report: dict, loss, holdout_png=None) -> str:
    """``report.html`` of ``mi-loop fit-images``: coloured by the albedo, with photos, renders and frusta.

    Parameters
    ----------
    result : mi_loop.fitting.images.ImageFitResult
        The fit: control mesh ``V``, ``F``.
    view : tuple ``(V (k, 3), F (m, 3), N (k, 3), colours (k, 3))``
        The viewer's limit tessellation with the albedo carried to it.
    views : list of mi_loop.io.View
        The fitted photos (their cameras are drawn).
    evaluation : dict
        ``targets`` and ``end['images']``: photos and renders of the fit (linear RGB) of the ``shown`` views.
    shown : list of int
        Indices into ``views`` of the pictures in ``evaluation``.
    report : dict
        The job's ``report.json``.
    loss : (h, w, 3) uint8 NumPy array
        The loss plot.
    holdout_png : (h, w, 3) float NumPy array, optional
        ``holdout.png`` (:func:`~mi_loop.app.image_report.holdout_grid`), shown with
        ``report['holdout']``'s scores as a table.

    Returns
    -------
    str
    """
    from mi_loop.io.srgb import linear_to_srgb

    V, F, N, C = view
    centre = V.mean(0)
    depth = 0.25 * float(np.median([np.linalg.norm(v.camera.c2w[:3, 3] - centre) for v in views]))
    photos = []
    for i, photo, render in zip(shown, evaluation["targets"], evaluation["end"]["images"]):
        loss_end = report["views"][i]["loss_end"]
        photos.append((f"{views[i].name}: L1 {loss_end:.4f}",
                       *(png_bytes(linear_to_srgb(np.clip(np.asarray(im)[..., :3], 0, 1))) for im in (photo, render))))
    tables = {"views (mean L1, linear RGB)": {v["name"]: f"{v['loss_start']:.4f} -> {v['loss_end']:.4f}"
                                              for v in report["views"]},
              "stages": {f"stage {k}": f"{s['n_vertices']} vertices at {s['width']}x{s['height']}, "
                                       f"{s.get('iterations', '')} iterations" for k, s in enumerate(report["stages"])}}
    figures = []
    if report.get("holdout"):
        held = report["holdout"]
        tables["held-out photos: silhouette IoU, PSNR (sRGB, inside the mask)"] = {
            **{f"{v['index']}: {v['name']}": f"{_score(v['iou'], 3)}, {_score(v['psnr_db'], 2)} dB"
               for v in held["views"]},
            "median": f"{held['iou_median']:.3f}, {held['psnr_median_db']:.2f} dB",
            "mean": f"{held['iou_mean']:.3f}, {held['psnr_mean_db']:.2f} dB"}
        figures.append((f"{len(held['views'])} photos held out of the fit (--holdout {held['k']}): photos, renders "
                        "of the fit, silhouettes (white both, red the photo's mask only, blue the render only)",
                        png_bytes(holdout_png)))
    return html_report.static_page(
        "mi-loop fit-images", V, F, N, subtitle=f"{report['input']}: {len(views)} photos, {len(result.V)} control "
        "vertices", colors=C, cage=(result.V, result.F), frusta=frustum_segments([v.camera for v in views], depth),
        tables=tables, loss_png=png_bytes(loss), photos=photos, figures=figures)


def _score(x, digits: int) -> str:
    """A score for a table: ``digits`` decimals, ``-`` where none (null)."""
    return "-" if x is None else f"{x:.{digits}f}"


def sequence_report(view, names, targets, cages, rows, fps: float, *, title: str = "mi-loop fit-sequence") -> str:
    """``report.html`` of ``mi-loop fit-sequence``.

    Parameters
    ----------
    view : tuple ``(V (T, k, 3), F (m, 3), N (T, k, 3), colours (T, k, 3) or None)``
        The viewer's limit tessellation of every finished frame.
    names : list of str
        The frames' names.
    targets : callable
        ``targets(i)``: the target of the ``i``-th finished frame, ``('mesh', V, F)`` or ``('points', P, N)``
        (the clean reference where there is one).
    cages : tuple ``(V_c (T, n, 3), F_c (f, 3))``
        The control mesh of every frame.
    rows : list of mi_loop.io.runs.MetricsRow
        ``metrics.csv``'s rows, one per finished frame.
    fps : float
        Frame rate of the player.
    title : str

    Returns
    -------
    str
    """
    V, F, N, C = view
    distances = np.stack([vertex_distances(V[i], targets(i), N[i]) for i in range(len(V))])

    def column(key):
        return [np.nan if getattr(r, key) is None else float(getattr(r, key)) for r in rows]

    plots = {"frames": [r.frame for r in rows], "panels": [
        {"title": "distance to the target / bbox diagonal", "series": {"mean": column("mean"), "RMS": column("rms")}},
        {"title": "flipped area, % of the surface", "series": {"flipped": column("flipped_pct")}},
        {"title": "correspondence drift / bbox diagonal",
         "series": {"mean": column("drift_mean"), "p95": column("drift_p95")}}]}
    last = rows[-1]
    tables = {"last frame": {"name": last.name, **{k: column(k)[-1] for k in ("mean", "rms", "hausdorff",
                                                                                "flipped_pct")}}}
    return html_report.sequence_page(
        title, V, F, N, names=names, fps=fps, subtitle=f"{len(V)} frames, {cages[0].shape[1]} control vertices",
        distances={"the frame's target": distances}, colors=C, cages=cages, plots=plots, tables=tables)
