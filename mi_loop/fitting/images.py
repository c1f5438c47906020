"""Shape and albedo of a Loop surface from calibrated photos, coarse to fine.

:func:`fit_images` fits control points ``x`` and a per-control-vertex albedo
``c`` to photos with known cameras and lighting, minimising the mean L1 image
loss of :class:`~mi_loop.render.images.ImageRenderer` (silhouettes and shading)
plus a small uniform-Laplacian term that keeps the cage spread:

``E(x, c) = mean_k |R_k(x, c) - T_k|_1 + laplacian |L x|^2 / (n d^2)``.

Stages: the start mesh (an icosphere or a template of the visual hull) is
refined ``refinements`` times by one exact Loop step (``x <- S x``, ``c <- S c``:
the same limit surface and colour field, with four times the control
faces), when the loss stalls or the stage's share of the iterations is
spent; the images are rendered at half the resolution per coarser stage.
Each stage is one run of the optimisation loop (:func:`mi_loop.fitting.loop.optimise`)
with the image term and the cage's Laplacian term
(:mod:`mi_loop.fitting.terms`). Each step is a "large step": the control points
are parameterised as ``u = (I + lambda L) x`` (:mod:`mi_loop.ad.smoothing`,
solved on the device), so the gradient is smoothed by ``(I + lambda L)^{-1}``
over the cage, and applied by a uniform Adam; a stage ends early when the
mean loss over two sweeps of the photos stops falling (the loop's convergence
test). No file I/O here (see :mod:`mi_loop.app.images_job`).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from mi_loop.errors import fail
from mi_loop.fitting.options import ImageFitOptions
from mi_loop.fitting.rules import Seeds

__all__ = ["HULL_RESOLUTION", "ImageFitResult", "fit_images", "refine", "stage_plan", "start_lighting",
           "start_mesh", "tessellation_level"]

#: Voxels along each side of the visual hull's grid (:func:`mi_loop.fitting.hull.carve`).
HULL_RESOLUTION = 96


@dataclass
class ImageFitResult:
    """What :func:`fit_images` found.

    Attributes
    ----------
    V : (n, 3) float64 NumPy array
        Control points (world units).
    F : (m, 3) int64 NumPy array
        Control faces.
    albedo : (n, 3) float64 NumPy array
        Per-control-vertex linear RGB.
    V0, F0, albedo0 : NumPy arrays
        The start mesh and albedo.
    history : list of dict
        Per iteration: ``stage``, ``loss`` (mean over its views), ``time`` (s since the start).
    stages : list of dict
        Per stage: ``n_vertices``, ``level``, ``width``, ``height``, ``iterations``,
        ``stalled`` (ended on the stall rule), ``time_s``.
    bbox : ((3,), (3,)) float64
        The visual hull's box (sets the scale of the steps).
    start : dict
        How the start mesh was made: ``init``; ``hull``, the carving's counts
        (:attr:`mi_loop.fitting.hull.Carving.info`, and ``unoriented``: boundary
        points without a normal, left out); ``template``, the template's
        ``n_points``, ``dropped_normals``, ``vertices``, ``faces``, ``genus``,
        ``boundary_edges``. Empty for a given start mesh.
    lighting : mi_loop.render.lighting.Lighting or None
        The estimated lighting (``options.lighting = 'sh'``): its coefficients
        and the gain of each of the views fitted, in their order.
    """

    V: np.ndarray
    F: np.ndarray
    albedo: np.ndarray
    V0: np.ndarray
    F0: np.ndarray
    albedo0: np.ndarray
    history: list = field(default_factory=list)
    stages: list = field(default_factory=list)
    bbox: tuple = ()
    start: dict = field(default_factory=dict)
    lighting: object = None


def refine(V, F, albedo=None):
    """One exact Loop step of a control mesh (and of a per-vertex attribute).

    Parameters
    ----------
    V : (n, 3) float NumPy array
        Control points.
    F : (m, 3) int NumPy array
        Control faces.
    albedo : (n, c) float NumPy array, optional
        Per-vertex attribute, refined by the same matrix.

    Returns
    -------
    V_fine : (n + e, 3) float64 NumPy array
    F_fine : (4 m, 3) int64 NumPy array
        Children of face ``f`` are rows ``4 f .. 4 f + 3`` (see
        :func:`mi_loop.subdivision_matrix`); the limit surface is unchanged.
    albedo_fine : (n + e, c) float64 NumPy array or None
        Within the range of ``albedo`` per channel (the Loop weights are a
        partition of unity: only rounding could leave it, and is clipped).
    """
    from mi_loop.subdiv.subdivision import subdivision_matrix

    S, F_fine = subdivision_matrix(F, len(V))
    if albedo is None:
        return S @ np.asarray(V, dtype=np.float64), F_fine, None
    A = np.asarray(albedo, dtype=np.float64)
    # each fine value is a convex combination of coarse ones: clipping to their range removes only rounding
    # (an albedo of exactly 1 would otherwise come out as 1.0000000000000002 and be refused)
    return S @ np.asarray(V, dtype=np.float64), F_fine, np.clip(S @ A, A.min(axis=0), A.max(axis=0))


def start_mesh(views, options: ImageFitOptions):
    """The start control mesh: an icosphere in the visual hull's box, or a template of the hull.

    Parameters
    ----------
    views : sequence of mi_loop.io.capture.View
        The photos (their masks and cameras).
    options : ImageFitOptions
        ``init``, ``n_vertices``, ``refinements``, ``seed``.

    Returns
    -------
    V : (n, 3) float64 NumPy array
    F : (m, 3) int64 NumPy array
    bbox : ((3,), (3,)) float64 NumPy arrays
        The visual hull's box.

    Raises
    ------
    ValueError
        Nothing left of the grid after carving (masks that contradict each other).
    """
    return _start_mesh(views, options)[:3]


def _start_mesh(views, options: ImageFitOptions):
    """:func:`start_mesh` and what it did: ``(V, F, bbox, info)``, ``info`` the carving's counts and the template's."""
    from mi_loop.datasets import icosphere
    from mi_loop.fitting.hull import carve, hull_points

    carving = carve(views, resolution=HULL_RESOLUTION)
    if not carving.occupied.any():
        fail("fit_images", "masks whose foregrounds overlap in space (a visual hull)", "nothing left after carving")
    kept = carving.centres[carving.occupied]
    bbox = (kept.min(axis=0), kept.max(axis=0))
    info = {"init": options.init, "hull": dict(carving.info)}
    n0 = options.n_vertices
    for _ in range(options.refinements):      # closed genus 0: one step maps n to 4 n - 6
        n0 = (n0 + 6) // 4
    if options.init == "sphere":
        s = max(s for s in range(8) if 10 * 4 ** s + 2 <= max(n0, 12)) if n0 >= 12 else 0
        V, F = icosphere(s)
        lo, hi = bbox
        return 0.5 * (lo + hi) + V * (0.5 * (hi - lo)), F, bbox, info
    from mi_loop.fitting.template import make_template

    P, N, unoriented = hull_points(carving)
    V, F, tinfo = make_template(P, N, max(n0, 12), seed=options.seed, zero_normals="drop")
    info["hull"]["unoriented"] = unoriented
    info["template"] = {k: tinfo[k] for k in ("n_points", "dropped_normals", "vertices", "faces", "genus",
                                              "boundary_edges")}
    return V, F, bbox, info


def tessellation_level(n_faces: int, triangles: int) -> int:
    """Return the tessellation level (0..6) whose ``n_faces * 4**level`` triangles are nearest ``triangles``.

    Parameters
    ----------
    n_faces : int
        Control faces.
    triangles : int
        Wanted rendered triangles.

    Returns
    -------
    int

    Examples
    --------
    >>> tessellation_level(320, 20_000), tessellation_level(5120, 20_000)
    (3, 1)
    """
    return int(np.clip(np.round(np.log(triangles / n_faces) / np.log(4)), 0, 6))


def stage_plan(options: ImageFitOptions, size: tuple[int, int], n_faces: int) -> list[dict]:
    """Resolution scale, tessellation level and iteration budget of each stage.

    Parameters
    ----------
    options : ImageFitOptions
    size : (int, int)
        The photos' largest (width, height).
    n_faces : int
        Faces of the start control mesh (each stage has four times the previous).

    Returns
    -------
    list of dict
        ``scale`` (image scale factor), ``level``, ``iterations`` per stage.
    """
    finest = 1.0 if options.resolution is None else min(1.0, options.resolution / max(size))
    n_stages = options.refinements + 1
    plan = []
    for k in range(n_stages):
        plan.append({"scale": finest * 0.5 ** (n_stages - 1 - k),
                     "level": tessellation_level(n_faces * 4 ** k, options.triangles),
                     "iterations": options.iterations // n_stages + (k < options.iterations % n_stages)})
    return plan


def fit_images(views, emitters, options: ImageFitOptions | None = None, *, start=None, progress=None):
    """Fit a Loop control mesh and its albedo to calibrated photos (module docstring).

    Parameters
    ----------
    views : sequence of mi_loop.io.capture.View
        Photos with masks and cameras (at the finest stage's size or larger; stages resize them).
    emitters : list of dict or mi.Emitter
        The capture's lighting, e.g. ``[{"type": "constant"}]``.
    options : ImageFitOptions, optional
    start : ((n, 3), (m, 3)) NumPy arrays, optional
        Start control mesh instead of ``options.init`` (it is refined like the others).
    progress : callable, optional
        ``progress(done, total, stage, loss)`` after each iteration.

    Returns
    -------
    ImageFitResult

    Raises
    ------
    FitError
        If the loss stops being finite.
    ValueError
        If fewer than two views are given.
    """
    options = options or ImageFitOptions()
    views = list(views)
    if len(views) < 2:
        fail("fit_images", "at least two photos", f"{len(views)}")
    t0 = time.perf_counter()
    if start is None:
        V, F, bbox, how = _start_mesh(views, options)
    else:
        V, F = (np.asarray(a) for a in start)
        V, F = V.astype(np.float64), F.astype(np.int64)
        bbox, how = (V.min(axis=0), V.max(axis=0)), {}
    c = np.full(V.shape, float(options.albedo))
    result = ImageFitResult(V=V, F=F, albedo=c, V0=V.copy(), F0=F.copy(), albedo0=c.copy(), bbox=bbox, start=how,
                            lighting=start_lighting(views, options.albedo) if options.lighting == "sh" else None)
    size = (max(v.camera.width for v in views), max(v.camera.height for v in views))
    plan = stage_plan(options, size, len(F))
    total = sum(p["iterations"] for p in plan)
    done = 0
    seeds = Seeds(options.seed)
    diag = float(np.linalg.norm(bbox[1] - bbox[0]))
    for k, stage in enumerate(plan):
        if k:
            V, F, c = refine(V, F, c)
        t_stage = time.perf_counter()
        V, c, info = _fit_stage(V, F, c, [v.resized(stage["scale"]) if stage["scale"] < 1 else v for v in views],
                                emitters, options, stage, k, diag, seeds, done, total, progress, result.lighting)
        h = info.pop("history")
        result.history += [{"stage": k, "loss": loss, "time": t_stage - t0 + s}
                           for loss, s in zip(h["image"], h["time"])]
        done += info["iterations"]
        result.stages.append({"n_vertices": len(V), "level": stage["level"], "scale": stage["scale"],
                              **info, "time_s": time.perf_counter() - t_stage})
    result.V, result.F, result.albedo = V, F, c
    return result


def start_lighting(views, albedo: float = 0.5):
    """The estimated lighting's start: uniform shading at the level that makes a grey ``albedo`` show the photos'
    mean colour inside their masks, every gain 1.

    Parameters
    ----------
    views : sequence of mi_loop.io.capture.View
    albedo : float
        The start albedo (grey), in (0, 1].

    Returns
    -------
    mi_loop.render.lighting.Lighting
        With one gain per view.
    """
    from mi_loop.render.lighting import N_COEFFS, Lighting, sh_basis

    inside = [v.rgb[v.mask >= 1.0] for v in views]
    colour = np.concatenate(inside).mean(axis=0) if sum(len(i) for i in inside) else np.full(3, 0.5)
    S = np.zeros((N_COEFFS, 3))
    S[0] = np.maximum(colour, 1e-3) / max(float(albedo), 1e-3) / sh_basis(np.array([[0.0, 0.0, 1.0]]))[0, 0]
    return Lighting(len(views), S)


def _fit_stage(V, F, c, views, emitters, options, stage, k, diag, seeds, done, total, progress, lighting):
    """Optimise one control mesh at one resolution: ``V``, ``c`` and the stage's record (with its history).
    An estimated ``lighting`` is optimised with them and left holding its estimate."""
    import mitsuba as mi

    from mi_loop.ad.smoothing import SmoothParameterisation
    from mi_loop.fitting import terms
    from mi_loop.fitting.loop import Parameter, optimise
    from mi_loop.fitting.optimisers import Adam, Constant, Exponential
    from mi_loop.fitting.rules import Convergence, Failure, Refresh
    from mi_loop.render.images import ImageRenderer

    n, n_it = len(V), stage["iterations"]
    renderer = ImageRenderer(V, F, views, emitters, albedo=c, level=stage["level"], spp=options.spp,
                             integrator=options.integrator, deterministic=options.deterministic,
                             lighting=lighting, highlights=options.highlights)
    smooth = SmoothParameterisation(F, n, options.lam)
    albedo = mi.Float(np.asarray(c, dtype=np.float32).ravel())
    params = {"x": Parameter(smooth.to_parameters(mi.Float(np.asarray(V, dtype=np.float32).ravel())),
                             Adam(uniform=True), Exponential(options.lr * diag, options.lr_decay, n_it),
                             parameterisation=smooth)}
    if options.albedo_lr > 0:
        params["albedo"] = Parameter(albedo, Adam(), Constant(options.albedo_lr), bounds=(0.0, 1.0))
    params |= terms.lighting_parameters(lighting, options.light_lr, options.exposure)
    parts = [terms.ImageTerm(renderer, albedo, views_per_iteration=options.views_per_iteration,
                             seeds=seeds.child(k))]
    if options.laplacian > 0:
        parts.insert(0, terms.CageLaplacian(F, n, options.laplacian / (n * diag ** 2)))
    if options.albedo_smooth > 0 and "albedo" in params:
        parts.insert(0, terms.CageLaplacian(F, n, options.albedo_smooth / n, of="albedo"))
    per_sweep = max(1, int(np.ceil(len(views) / options.views_per_iteration)))
    # stall: two sweeps of the photos whose mean loss falls by less than tolerance, after half the stage
    stall = Convergence(options.tolerance, patience=0, halvings=0, window=0, block=2 * per_sweep,
                        start=n_it // 2, monitor="image")
    result = optimise(params, parts, iterations=n_it, seeds=seeds.child(k), refresh=Refresh(n_it),
                      convergence=stall, failure=Failure("fit_images", context=f"stage {k}, "),
                      progress=None if progress is None else (lambda i, _, loss: progress(done + i, total, k, loss)))
    c_fit = result.values["albedo"] if "albedo" in result.values else np.asarray(c, dtype=np.float64)
    terms.keep_lighting(lighting, result.values)
    return result.values["x"], c_fit, {"iterations": result.iterations, "stalled": result.converged,
                                       "width": views[0].camera.width, "height": views[0].camera.height,
                                       "history": result.history}
