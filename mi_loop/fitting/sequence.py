"""Frame-by-frame fitting of one control mesh to a deforming sequence: depth, meshes and photos together.

Per frame ``t`` the control points ``V`` take Adam steps on the sum of the gradients of

    E_t = mean_j f_t(Q_j)^2 + cover E_cover + alpha E_arap(V; V_{t-1}) / n
          + alpha_rest E_arap(V; V_template) / n
          + fold mean_j max(0, 1/2 - n_j . n_j^{t-1})^2 + image term,

``f_t`` the IMLS function of the frame's points (partial, noisy depth, or
samples of a mesh frame), ``E_cover`` the coverage term, ARAP relative to the
previous frame's fit (the warm start) and to the template (so that the cage
cannot drift into folds over a long sequence), a barrier on limit normals
that turned by more than 60 degrees since the previous frame's fit (a fold
in the making; by default ``cover`` is 3 and ``fold`` 0.01 on a mesh frame, 0.3 (3 with photos) and 1 on a
point cloud: :meth:`~mi_loop.fitting.options.SequenceOptions.cover_weight`, ``fold_weight``), and the image
term: mean L1
between ``direct_projective`` renders of the limit surface (``loop_subdiv``,
exact limit normals) and the frame's photos (with a per-control-vertex albedo,
estimated on the first frame and refined slowly after) or renders of a mesh
frame from a rig of cameras (:class:`FrameImages`).

Each frame is one run of the optimisation loop (:func:`mi_loop.fitting.loop.optimise`)
with the terms of :mod:`mi_loop.fitting.terms`, stepped by Adam (the default) or by
Gauss-Newton through the terms' matrices (``options.solver``; :class:`~mi_loop.fitting.optimisers.GaussNewton`,
its matrix rebuilt every :data:`GN_REFRESH` steps). Every step passes the fold guard
(:class:`~mi_loop.fitting.guard.FoldGuard`): it is shortened where it would turn a control
triangle over or flip a limit normal against the previous frame's. With photos of the
previous frame, ``options.flow`` adds the optical-flow term (:mod:`mi_loop.fitting.flow`). The image term
(:class:`~mi_loop.fitting.terms.ImageTerm`) acts over the whole frame. Its
gradient is refreshed every ``options.image_every`` iterations (a render and
its reverse pass cost ten times a geometric iteration) and added to every
step's geometric gradient in between. It is balanced per control vertex
(:class:`ImageBalance`), on the device:

- ``k``, fixed at the frame's first refresh, scales the image gradient to the
  RMS of the geometric gradient over the vertices the data supports, so that
  ``beta`` is a relative weight whatever the units of the two losses;
- the image gradient is smoothed, ``(I + lambda L)^-1 g`` with
  ``lambda = options.lam`` (a Sobolev gradient, as in Nicolet et
  al. 2021): Adam normalises each coordinate's step, so unsmoothed Monte
  Carlo noise would move vertices by full steps where depth does not hold them;
- each vertex's image weight is ``beta k (w + (1 - w) (1 - s_i))``,
  ``s_i`` in [0, 1] the data support at its limit point (:func:`support`:
  1 within three point spacings of a data point facing the same way, 0
  beyond six): where depth does not see the surface the images hold it
  alone (with ARAP); where it does, they count ``w = options.seen`` as much.
- samples of a mesh frame cover the whole surface (``complete``): there
  every vertex counts as seen, ``s_i = 1``, and ``w = seen min(1, (sigma /
  (p / 2))^2)``, the mesh's roughness ``sigma`` (residuals of local quadric
  fits, :func:`~mi_loop.mesh.points.noise_level`) against half a pixel's
  width ``p`` at the subject: inverse-variance weighting, so renders refine a
  noisy mesh but leave an accurate one alone (below :data:`MIN_IMAGE_WEIGHT`
  the renders are skipped). Depth point clouds keep
  ``w = seen``: their errors are not only noise (one-sided views, grazing
  rays, holes), and there the photos at the seen parts measurably help.

IMLS reaches only ``h0 2^reach`` from each sample (:class:`~mi_loop.energies.imls.IMLS`
``max_growths``): a sample on a side the depth cameras never saw is not
pulled onto the seen side. No file I/O here.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mi_loop.fitting.options import SequenceOptions

__all__ = ["MIN_IMAGE_WEIGHT", "FrameImages", "ImageBalance", "Rig", "SequenceOptions", "fit_frame", "pixel_size",
           "support"]

#: A mesh frame's renders are skipped when their weight ``beta w`` (relative to the geometric gradient) is below.
MIN_IMAGE_WEIGHT = 0.01
#: Gauss-Newton steps between refreshes of the neighbour lists and of the matrix.
GN_REFRESH = 2
#: Levenberg damping of the Gauss-Newton steps, relative to the matrix's mean diagonal, in the metric
#: ``(I + L) (x) I_3`` (``L`` the cage's graph Laplacian): rough steps are damped more than smooth ones.
GN_DAMPING = 1e-3
#: With an image term, the largest step of a control point in one Gauss-Newton step, in mean control-edge
#: lengths (a trust region: the image gradient, which has no matrix, would otherwise be divided by ARAP's
#: alone where the data are flat).
GN_REACH = 0.1
#: Where the tangential hold of a tracked mesh frame lets go (:class:`~mi_loop.fitting.terms.Tangential`'s
#: ``reach``), in mean control-edge lengths: slides the data do not ask for are far smaller, a mis-tracked
#: limb's larger.
TANGENTIAL_REACH = 0.5
#: The tangential hold's weight on a tracked point-cloud frame, relative to a mesh frame's: there the hold is
#: quadratic and a part without data is unseen, so the graph's shape is the best guess for it (on the spot
#: capture 3 halves the drift and the flipped area against 1; on a mesh frame 3 keeps mis-tracked legs).
POINTS_HOLD = 3.0


def support(Q, tree, radius: float, normals=None, data_normals=None) -> np.ndarray:
    """Data support of points ``Q``: 1 within ``radius`` of a data point, 0 beyond ``2 radius``, linear between.

    With ``normals`` (at ``Q``) and ``data_normals``, only data points whose
    normal is within 90 degrees of the point's count (of the 8 nearest): the
    far side of a thin part is not supported by points on its near side.

    Parameters
    ----------
    Q : (k, 3) float NumPy array
        Points (control-vertex limit points).
    tree : scipy.spatial.cKDTree
        Of the data points.
    radius : float
        Full support within it.
    normals, data_normals : (k, 3) and (N, 3) float NumPy arrays, optional

    Returns
    -------
    (k,) float64 NumPy array

    Examples
    --------
    >>> from scipy.spatial import cKDTree
    >>> support(np.array([[0.0, 0, 0], [0.15, 0, 0], [1.0, 0, 0]]), cKDTree([[0.0, 0, 0]]), 0.1).round(6).tolist()
    [1.0, 0.5, 0.0]
    >>> support(np.zeros((1, 3)), cKDTree([[0.0, 0, 0]]), 0.1, np.array([[0.0, 0, 1]]), np.array([[0.0, 0, -1]]))
    array([0.])
    """
    Q = np.asarray(Q, dtype=np.float64)
    if normals is None:
        d, _ = tree.query(Q, workers=-1)
    else:
        k = min(8, tree.n)
        d, i = tree.query(Q, k=k, workers=-1)
        d, i = d.reshape(len(Q), k), i.reshape(len(Q), k)
        facing = np.einsum("qkd,qd->qk", data_normals[i], normals) > 0
        d = np.where(facing, d, np.inf).min(axis=1)
    return np.clip((2.0 * radius - d) / radius, 0.0, 1.0)


def pixel_size(cameras, centre, scale: float = 1.0) -> float:
    """Median over the cameras of one pixel's width at ``centre``, divided by ``scale`` (into the fit's units).

    Parameters
    ----------
    cameras : sequence of mi_loop.io.capture.Camera
    centre : (3,) float array-like
        The subject's centre, in the cameras' units.
    scale : float
        Size of one fit unit in the cameras' units (the unit box's ``scale``).

    Returns
    -------
    float
        ``median_k |c_k - centre| / fx_k / scale``.
    """
    centre = np.asarray(centre, dtype=np.float64)
    widths = [np.linalg.norm(c.c2w[:3, 3] - centre) / c.fx for c in cameras]
    return float(np.median(widths)) / float(scale)


@dataclass
class FrameImages:
    """What a frame's image term renders and with what: the renderer, the albedo, the units.

    Attributes
    ----------
    renderer : mi_loop.render.images.ImageRenderer or callable
        The frame's targets (photos, or renders of a mesh frame) and cameras;
        or a function returning it, called only if the frame renders at all
        (a mesh frame whose renders would weigh too little never renders its targets).
    albedo : (n, 3) float NumPy array
        Per-control-vertex linear albedo at the start of the frame.
    albedo_lr : float
        Step of the albedo in this frame (0: kept as it is).
    albedo_optimiser : Adam or None
        The albedo's optimiser, carried from frame to frame (None: a new one).
    to_world : (float, (3,) array) or None
        ``(scale, centre)`` from the fit's unit box to the renderer's units
        (photos in the capture's units); None: the same units (the rig).
    pixel : float
        Width of one pixel at the subject, in the fit's units.
    light_lr : float
        Step of the renderer's estimated lighting (its ``lighting``, where it has
        one) in this frame; 0: kept as it is.
    exposure : bool
        Estimate the photos' gains too (with ``light_lr``).
    flow : (list of View, list of View) or None
        The photos of the previous frame and of this one, camera by camera:
        the optical-flow term's (``options.flow``, :mod:`mi_loop.fitting.flow`); None: no such term.
    photos : bool
        The targets are photos (False: renders of a mesh frame).
    """

    renderer: object
    albedo: np.ndarray
    albedo_lr: float = 0.0
    albedo_optimiser: object = None
    to_world: tuple | None = None
    pixel: float = 1.0
    light_lr: float = 0.0
    exposure: bool = True
    flow: tuple | None = None
    photos: bool = False


class Rig:
    """The camera rig of mesh frames without photos: cameras around a fixed box, its lights, one renderer.

    Each frame's mesh is rendered from the rig (the targets) and the limit
    surface against them, grey diffuse (``options.mode`` 'shading') or black
    (``'silhouette'``), by one :class:`~mi_loop.render.images.ImageRenderer`
    kept for the whole sequence.

    Parameters
    ----------
    options : SequenceOptions
        ``views``, ``resolution``, ``mode``, ``level``, ``spp``, ``target_spp``,
        ``loss``, ``deterministic``, ``seed``.
    box : ((3,), (3,)) float array-like
        The box the cameras frame, in the fit's units (fixed for the sequence).
    """

    def __init__(self, options: SequenceOptions, box):
        from mi_loop.render.cameras import rig_cameras
        from mi_loop.render.scene import rig_emitters

        lo, hi = (np.asarray(c, dtype=np.float64) for c in box)
        self.options, self.centre = options, 0.5 * (lo + hi)
        self.cameras = rig_cameras(options.views, (lo, hi), options.resolution)
        self.emitters = rig_emitters((lo, hi), options.mode)
        self.grey = 0.6 if options.mode == "shading" else 0.0
        self.renderer = None

    def images(self, x0, F, mesh, frame: int) -> FrameImages:
        """The :class:`FrameImages` of a frame: renders of its ``mesh`` ``(V, F)`` (fit's units), made when used.

        Parameters
        ----------
        x0 : (n, 3) float NumPy array
            Control points the renderer is first built with.
        F : (m, 3) int NumPy array
            Control faces.
        mesh : ((k, 3), (t, 3)) NumPy arrays
            The frame's mesh.
        frame : int
            The frame (seeds its target renders).
        """
        return FrameImages(lambda: self._renderer(x0, F, mesh, frame), np.full((len(x0), 3), self.grey),
                           pixel=pixel_size(self.cameras, self.centre))

    def _renderer(self, x0, F, mesh, frame):
        from mi_loop.fitting.rules import Seeds
        from mi_loop.mesh.geometry import vertex_normals
        from mi_loop.render.captures import render_targets
        from mi_loop.render.images import ImageRenderer

        o = self.options
        Vt, Ft = mesh
        targets = render_targets(Vt, Ft, self.cameras, self.emitters, albedo=np.full((len(Vt), 3), self.grey),
                                 normals=vertex_normals(Vt, Ft), spp=o.target_spp,
                                 seed=Seeds(o.seed).child(frame).integer(2))
        if self.renderer is None or not self.renderer.set_photos(targets):
            self.renderer = ImageRenderer(x0, F, targets, self.emitters, albedo=np.full((len(x0), 3), self.grey),
                                          level=o.level, spp=o.spp, loss=o.loss, deterministic=o.deterministic)
        return self.renderer


class ImageBalance:
    """Smoothing, per-vertex weights and scale of a frame's image gradient (module docstring).

    Parameters
    ----------
    F : (m, 3) int NumPy array
        Control faces.
    n : int
        Control vertices.
    options : SequenceOptions
        ``beta``, ``lam``, ``seen``, ``geometric``.
    seen_weight : float
        ``w``: the image weight where the data supports the surface (relative).
    imls : IMLS or None
        The frame's data (None: images only, the same weight everywhere).
    vertex_op : LimitOperator or None
        One sample per control vertex, with derivatives (the support is measured at its limit points).
    radius : float or None
        Full support within it; None with ``complete``.
    complete : bool
        The data cover the whole surface: every vertex counts as supported.
    """

    def __init__(self, F, n: int, options: SequenceOptions, seen_weight: float, imls=None, vertex_op=None,
                 radius=None, complete: bool = False):
        from mi_loop.ad.smoothing import SmoothParameterisation

        self.options, self.w, self.n = options, float(seen_weight), int(n)
        self.imls, self.vertex_op, self.radius, self.complete = imls, vertex_op, radius, bool(complete)
        self.smooth = SmoothParameterisation(F, n, options.lam) if options.lam > 0 else None
        self.k, self.seen, self._weights, self._s = None, 1.0, None, None

    def refresh(self, state) -> None:
        """The weights follow the surface: recomputed at the next image gradient."""
        self._weights = None

    def _update(self, state) -> None:
        import drjit as dr
        import mitsuba as mi

        if self.imls is None:                                      # images only: one weight everywhere
            w, s = np.full(self.n, self.options.beta), None
        elif self.complete:                                        # a mesh frame sees every part of the surface
            w, s = np.full(self.n, self.options.beta * self.w), np.ones(self.n)
        else:
            V = state.numpy("x")
            Q, Nq = V, None
            if self.vertex_op is not None:
                with dr.suspend_grad():
                    x = mi.Float(V.ravel().astype(np.float32))
                    Q = np.array(self.vertex_op.positions(x), dtype=np.float64).T
                    Nq = np.array(self.vertex_op.normals(x), dtype=np.float64).T
            s = support(Q, self.imls.tree, self.radius, Nq, self.imls.normals if Nq is not None else None)
            w = self.options.beta * (self.w + (1.0 - self.w) * (1.0 - s))
        self._s = s
        self.seen = float(np.mean(s > 0.5)) if s is not None else 0.0
        self._weights = mi.Float(np.repeat(w, 3).astype(np.float32))

    def __call__(self, g, state):
        """``k w_i (I + lambda L)^-1 g`` of the image gradient ``g`` (``mi.Float (3n)``)."""
        if self._weights is None:
            self._update(state)
        if self.smooth is not None:          # Sobolev gradient: the render noise averaged over neighbourhoods
            g = self.smooth.solve(g)
        if self.k is None:
            self.k = self._scale(np.array(state.grads["x"], dtype=np.float64).reshape(-1, 3),
                                 np.array(g, dtype=np.float64).reshape(-1, 3))
        return g * (self._weights * self.k)

    def _scale(self, g_geo, g_image) -> float:
        """``k``: RMS of the geometric gradient over supported vertices / RMS of the image gradient."""
        if not self.options.geometric:
            return 1.0
        s = self._s if self._s is not None else np.zeros(len(g_geo))
        supported = (s > 0.5) & (self.options.seen < 1)     # with seen 1 the weights do not tell them apart
        rows = g_geo[supported] if supported.any() else g_geo
        a = float(np.sqrt(np.mean(np.sum(rows ** 2, axis=1))))
        b = float(np.sqrt(np.mean(np.sum(g_image ** 2, axis=1))))
        return a / b if b > 0 else 0.0


def fit_frame(x0, F, points, normals, op, images: FrameImages | None, options: SequenceOptions, frame: int,
              lr: float, progress=None, *, rest=None, vertex_op=None, iterations: int | None = None,
              complete: bool = False, held=None, previous=None, crossings=None):
    """Fit the control points of one frame, warm-started from the previous frame's ``x0``.

    One run of the optimisation loop on ``E_t`` (module docstring):
    ``iterations`` steps (default ``options.iterations``; fewer when
    ``options.tolerance`` > 0 and the energy stops improving), the first half
    with ARAP ``options.stiff_factor`` times stiffer, the image gradient
    refreshed every ``options.image_every`` steps, the neighbour lists every 10.

    Parameters
    ----------
    x0 : (n, 3) float64 NumPy array
        Start control points (the previous frame's fit), in the unit box;
        also the ARAP rest shape unless ``previous`` is given.
    F : (m, 3) int64 NumPy array
        Control faces (one connectivity for the whole sequence).
    points, normals : (k, 3) float64 NumPy arrays or None
        The frame's oriented points, in the unit box; None when
        ``options.geometric`` is False.
    op : LimitOperator
        Limit samples of ``F`` for the distance terms (with derivatives: the
        facing test and the fold barrier use the limit normals).
    images : FrameImages or None
        The frame's image term (None, or ``options.image`` False: without).
    options : SequenceOptions
        Weights, iteration counts, views per refresh, seed.
    frame : int
        Frame index: the branch of the seed tree (``options.seed``, frame) the
        views and the renders' samplers come from.
    lr : float
        Largest Adam step (unit box); the step starts from the warm start's
        IMLS residual, capped by ``lr``.
    progress : callable, optional
        Called as ``progress(done, total)`` after every iteration.
    rest : (n, 3) float64 NumPy array, optional
        The template: second ARAP rest shape, weight ``options.rest_weight(...)``.
    vertex_op : LimitOperator, optional
        One sample per control vertex (its limit point), for the data support
        of the image weights; without it the control points stand in.
    iterations : int, optional
        Steps for this frame (the first frame takes more).
    complete : bool, optional
        The data cover the whole surface (samples of a mesh frame): every
        control vertex counts as supported, and the images weigh by the
        data's roughness against the pixel width (module docstring).
    held : (n,) float array-like, optional
        Given when ``x0`` is where the frame's coarse stage carried the previous fit
        (:mod:`mi_loop.fitting.track`): the control points are held there along the surface
        (:class:`~mi_loop.fitting.terms.Tangential`, weight ``options.tangential``), each by its weight
        in ``held`` (:func:`~mi_loop.fitting.track.anchor_weights`: how far the coarse stage is to be
        trusted there; more than 1 where photos pinned it). With ``complete`` data the hold also lets
        go beyond :data:`TANGENTIAL_REACH`: where the data cover the whole surface, a part that found
        none is one the stage lost (a limb that swung farther than the correspondences reach); partial
        depth leaves parts unseen, not lost, and holds them quadratically, :data:`POINTS_HOLD` times as
        hard (the tracked shape is the best guess the geometry gives).
    previous : (n, 3) float array-like, optional
        The previous frame's fit, ARAP's rest shape when ``x0`` is not it (a tracked start): where the coarse
        stage bent a part the data do not hold (a limb it lost), ARAP restores the part's fitted shape
        instead of keeping the bend. Default: ``x0``.
    crossings : CrossingTest, optional
        The fold guard also keeps every step from making the limit surface pass through itself
        where it did not (``options.no_crossing``; :class:`~mi_loop.fitting.guard.CrossingTest`).

    Returns
    -------
    V : (n, 3) float64 NumPy array
        Fitted control points, unit box.
    info : dict
        ``history`` (``geo``: the geometric energy per iteration, ``image``:
        the image loss, NaN between refreshes), ``time_render`` (seconds in
        the renders and their reverse passes), ``iterations``, ``image_scale``
        (``k``), ``seen`` (share of control vertices the data supports),
        ``noise``, ``seen_weight``, ``albedo`` (the frame's albedo, (n, 3), or None).

    Raises
    ------
    FitError
        If an energy is not finite (the message names the frame and the iteration).
    """
    import drjit as dr
    import mitsuba as mi
    import scipy.sparse as sp

    from mi_loop.ad.smoothing import smoothing_matrix
    from mi_loop.energies.arap import ARAP
    from mi_loop.energies.coverage import Coverage
    from mi_loop.energies.imls import IMLS
    from mi_loop.fitting import terms
    from mi_loop.fitting.guard import FoldGuard
    from mi_loop.fitting.loop import Parameter, optimise
    from mi_loop.fitting.optimisers import Adam, Constant, GaussNewton
    from mi_loop.fitting.rules import Convergence, Failure, Refresh, Seeds
    from mi_loop.mesh.geometry import mean_edge_length

    n = len(x0)
    gauss_newton = options.solver == "gauss-newton"
    n_it = int(iterations or options.frame_iterations(first=False))
    failure = Failure("fit_frame", context=f"frame {frame}, ")
    x = mi.Float(np.asarray(x0, dtype=np.float32).ravel())
    # rest = the previous frame's fit; Adam's first half is stiff (Gauss-Newton needs no such start)
    stiff = (options.stiff_factor, n_it // 2) if options.stiff_factor > 1 and not gauss_newton else None
    parts = [terms.Rigidity(ARAP(x0 if previous is None else previous, F), options.alpha / n, stiff=stiff)]
    photos = images is not None and images.photos
    alpha_rest = options.rest_weight(photos=photos)
    if rest is not None and alpha_rest > 0:
        parts.append(terms.Rigidity(ARAP(rest, F), alpha_rest / n, name="arap_rest"))
    normals0 = op.normals(x) if op.derivatives else None
    dr.eval(normals0)
    if held is not None and options.tangential > 0 and vertex_op is not None:
        N0 = np.array(vertex_op.normals(x), dtype=np.float64).T
        if complete:        # let go of far slides
            hold = terms.Tangential(x0, N0, options.tangential, held, reach=TANGENTIAL_REACH * mean_edge_length(x0, F))
        else:
            hold = terms.Tangential(x0, N0, POINTS_HOLD * options.tangential, held)
        parts.append(hold)
    fold = options.fold_weight(mesh_frame=complete)
    if fold > 0 and op.derivatives:   # the previous frame's limit normals: barrier against turning over
        parts.append(terms.Fold(op, fold, reference=normals0, opaque=True))
    imls = None
    if options.geometric:
        imls = IMLS(points, normals, max_growths=options.reach)
        parts.append(terms.Distance(imls, op, facing=op.derivatives))
        cover = options.cover_weight(mesh_frame=complete, photos=photos)
        if cover > 0:
            parts.append(terms.Coverage(Coverage(points, normals, tree=imls.tree), op, cover,
                                        facing=op.derivatives))
        # Step from the residual of the warm start (as in static fitting), capped by lr.
        Q0 = op.positions(x)
        N0 = None if normals0 is None else np.array(normals0, dtype=np.float64).T
        imls.update(np.array(Q0, dtype=np.float64).T, N0)
        e0 = float(imls.energy(Q0, reduce="mean")[0])
        if not np.isfinite(e0):
            raise failure.error(0, {"imls": e0})
        lr = float(np.clip(np.sqrt(e0) / 3.0, 1e-2 * lr, lr))
    seeds = Seeds(options.seed).child(frame)
    guard = None
    if op.derivatives:       # no step turns a control triangle over or flips a limit normal (against the last frame's)
        guard = FoldGuard(op, F, x0 if rest is None else rest, np.array(normals0, dtype=np.float64).T,
                          crossings=crossings)
    if gauss_newton:
        metric = sp.kron(smoothing_matrix(F, n, 1.0), sp.identity(3), format="csr")
        params = {"x": Parameter(x, GaussNewton(damping=GN_DAMPING, metric=metric), Constant(1.0),
                                 guard=guard)}
    else:
        params = {"x": Parameter(x, Adam(), Constant(lr), guard=guard)}
    if images is not None and images.flow is not None and options.flow > 0 and options.image:
        parts.append(_flow_term(op, x0, F, images, options.flow))
    balance, extra = _image_term(images, options, F, n, imls, vertex_op, complete, seeds, params, parts)
    if gauss_newton and balance is not None:
        params["x"].optimiser.max_step = GN_REACH * mean_edge_length(x0, F)
    result = optimise(params, parts, iterations=n_it, seeds=seeds, refresh=Refresh(GN_REFRESH if gauss_newton else 10),
                      convergence=Convergence(options.tolerance), failure=failure,
                      progress=None if progress is None else (lambda i, total, _: progress(i, total)))
    h = result.history
    info = {"history": {"geo": h["total"], "image": h.get("image", [np.nan] * result.iterations)},
            "time_render": result.seconds.get("image", 0.0), "iterations": result.iterations,
            "image_scale": None if balance is None or balance.k is None else float(balance.k),
            "seen": 1.0 if balance is None else balance.seen, **extra}
    if "albedo" in result.values:        # the fitted albedo, carried to the next frame
        info["albedo"] = result.values["albedo"]
    if images is not None and getattr(images.renderer, "lighting", None) is not None:
        terms.keep_lighting(images.renderer.lighting, result.values)     # kept by the renderer for the next frame
    return result.values["x"], info


def _flow_term(op, x0, F, images, weight: float):
    """The optical-flow term of a frame: the previous fit's samples, where the flow carried them (photos' units)."""
    import mitsuba as mi

    from mi_loop.fitting import terms
    from mi_loop.fitting.flow import flow_correspondences
    from mi_loop.subdiv.masks import limit_mesh

    scale, centre = images.to_world if images.to_world is not None else (1.0, np.zeros(3))
    x = mi.Float(np.asarray(x0, dtype=np.float32).ravel())
    Q, N = (np.array(a, dtype=np.float64).T for a in op.positions_normals(x))
    surface = limit_mesh(np.asarray(x0, dtype=np.float64) * scale + centre, F, level=2)[0]
    corr = flow_correspondences(*images.flow, Q * scale + centre, N, surface)
    return terms.Flow(op, corr, weight, (scale, centre), images.pixel)


def _image_term(images, options, F, n, imls, vertex_op, complete, seeds, params, parts):
    """Append the frame's image term to ``parts`` (and its albedo to ``params``); ``(balance, info)``."""
    import mitsuba as mi

    from mi_loop.fitting import terms
    from mi_loop.fitting.loop import Parameter
    from mi_loop.fitting.optimisers import Adam, Constant

    extra = {"noise": None, "seen_weight": float(options.seen)}
    if not options.image or images is None:
        return None, extra | {"albedo": None if images is None else np.asarray(images.albedo, dtype=np.float64)}
    seen_weight, radius = options.seen, None
    if imls is not None and complete:                 # a mesh frame: renders weigh by its roughness
        from mi_loop.mesh.points import noise_level

        extra["noise"] = noise_level(imls.points, tree=imls.tree)
        seen_weight = options.seen * min(1.0, (extra["noise"] / (0.5 * images.pixel)) ** 2)
        extra["seen_weight"] = float(seen_weight)
        if options.beta * seen_weight < MIN_IMAGE_WEIGHT:    # else the renders would move nothing
            return None, extra | {"albedo": np.asarray(images.albedo, dtype=np.float64)}
    elif imls is not None:                            # full support within three data spacings
        P = imls.points[::max(1, len(imls.points) // 2000)]
        radius = 3.0 * float(np.median(imls.tree.query(P, k=2)[0][:, 1]))
    albedo = mi.Float(np.asarray(images.albedo, dtype=np.float32).ravel())
    if images.albedo_lr > 0:
        opt = images.albedo_optimiser if images.albedo_optimiser is not None else Adam()
        params["albedo"] = Parameter(albedo, opt, Constant(images.albedo_lr), bounds=(0.0, 1.0))
    balance = ImageBalance(F, n, options, seen_weight, imls, vertex_op, radius, complete)
    renderer = images.renderer() if callable(images.renderer) else images.renderer
    params |= terms.lighting_parameters(getattr(renderer, "lighting", None), images.light_lr, images.exposure)
    parts.append(terms.ImageTerm(renderer, albedo, views_per_iteration=options.views_per_iteration,
                                 every=options.image_every, to_world=images.to_world, shaping=balance,
                                 seeds=seeds))
    return balance, extra | {"albedo": np.asarray(images.albedo, dtype=np.float64)}
