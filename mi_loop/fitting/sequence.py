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
in the making), and the image term: mean L1
between ``direct_projective`` renders of the limit surface (``loop_subdiv``,
exact limit normals) and the frame's photos (:class:`PhotoTerm`, with a
per-control-vertex albedo) or renders of a mesh frame (:class:`RenderedTerm`).

The image term acts over the whole frame. Its gradient is refreshed every
``options.image_every`` iterations (a render and its reverse pass cost ten
times a geometric iteration) and added to every step's geometric gradient in
between. It is balanced per control vertex:

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

import time

import numpy as np

from mi_loop.errors import FitError
from mi_loop.fitting.options import SequenceOptions

__all__ = ["MIN_IMAGE_WEIGHT", "PhotoTerm", "RenderedTerm", "SequenceOptions", "fit_frame", "support"]

#: A mesh frame's renders are skipped when their weight ``beta w`` (relative to the geometric gradient) is below.
MIN_IMAGE_WEIGHT = 0.01


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


class RenderedTerm:
    """Image term against renders of a mesh frame (:class:`~mi_loop.render.multiview.Renderer`).

    Parameters
    ----------
    renderer : Renderer
        The sequence's rig (fixed cameras, unit-box units).
    targets : list of mi.TensorXf, or a callable returning one
        The frame's target renders; a callable is called on the first
        gradient (a frame whose renders are skipped never renders them).
    """

    def __init__(self, renderer, targets):
        self.renderer, self._targets = renderer, targets
        self.n_views = len(renderer.views)

    @property
    def targets(self) -> list:
        """The target renders (rendered on first use when given as a callable)."""
        if callable(self._targets):
            self._targets = self._targets()
        return self._targets

    def pixel_size(self) -> float:
        """Width of one pixel at the subject's centre, in the fit's units (the rig's: unit box)."""
        from mi_loop.render.scene import look_at_distance

        lo, hi = (np.asarray(b, dtype=np.float64) for b in self.renderer.bbox)
        fov = 35.0                      # the rig's field of view (scene_dict's default)
        d = look_at_distance(0.5 * float(np.linalg.norm(hi - lo)), fov)
        return 2.0 * d * float(np.tan(np.radians(fov) / 2)) / self.renderer.options.resolution

    def gradient(self, V, view_ids, seed: int):
        """``(dL/dV (n, 3), L)`` at control points ``V`` (unit box) over ``view_ids``."""
        import drjit as dr
        import mitsuba as mi

        x = mi.Float(np.asarray(V, dtype=np.float32).ravel())
        dr.enable_grad(x)
        loss = self.renderer.backward(x, view_ids, self.targets, seed=seed)
        return np.asarray(dr.grad(x), dtype=np.float64).reshape(-1, 3), loss


class PhotoTerm:
    """Image term against a frame's photos (:class:`~mi_loop.render.photo.PhotoRenderer`), with albedo.

    The renderer works in the capture's units (its cameras and emitters); the
    fit in the unit box, so the control points are mapped by ``norm`` and the
    gradient back (``dL/dV = scale dL/dX``).

    Parameters
    ----------
    renderer : PhotoRenderer
        Scene of the frame's cameras and the capture's emitters.
    norm : Normalisation
        Unit box to capture units.
    albedo : (n, 3) float NumPy array
        Per-control-vertex linear albedo (updated in place of :attr:`albedo`).
    albedo_lr : float
        Adam step of the albedo (0: kept).
    state : AdamUniform, optional
        The albedo optimiser carried over from the previous frame.
    """

    def __init__(self, renderer, norm, albedo, albedo_lr: float, state=None):
        from mi_loop.fitting.largesteps import AdamUniform

        self.renderer, self.norm = renderer, norm
        self.n_views = len(renderer.views)
        self.albedo = np.asarray(albedo, dtype=np.float64).copy()
        self.albedo_lr = float(albedo_lr)
        self.opt = state if state is not None else AdamUniform(self.albedo, lr=max(self.albedo_lr, 1e-12),
                                                               uniform=False)
        self.opt.x, self.opt.lr = self.albedo.copy(), max(self.albedo_lr, 1e-12)

    def pixel_size(self) -> float:
        """Median over the cameras of one pixel's width at the subject's centre, in the fit's units (unit box)."""
        centre = np.asarray(self.norm.inverse(np.zeros(3)), dtype=np.float64)
        widths = [np.linalg.norm(v.camera.c2w[:3, 3] - centre) / v.camera.fx for v in self.renderer.views]
        return float(np.median(widths)) / self.norm.scale

    def gradient(self, V, view_ids, seed: int):
        """``(dL/dV (n, 3), L)`` at control points ``V`` (unit box); steps the albedo."""
        import drjit as dr
        import mitsuba as mi

        x = mi.Float(np.asarray(self.norm.inverse(V), dtype=np.float32).ravel())
        a = mi.Float(self.albedo.astype(np.float32).ravel())
        dr.enable_grad(x, a)
        losses = self.renderer.backward(x, a, view_ids, seed=seed)
        g = np.asarray(dr.grad(x), dtype=np.float64).reshape(-1, 3) * self.norm.scale
        if self.albedo_lr > 0:
            g_a = np.asarray(dr.grad(a), dtype=np.float64).reshape(-1, 3)
            self.albedo = np.clip(self.opt.step(g_a), 0.0, 1.0)
            self.opt.x = self.albedo.copy()
        return g, float(np.mean(losses))


def fit_frame(x0, F, points, normals, op, image, options: SequenceOptions, frame: int, lr: float,
              progress=None, *, rest=None, vertex_op=None, iterations: int | None = None, complete: bool = False):
    """Fit the control points of one frame, warm-started from the previous frame's ``x0``.

    Adam on the gradients of ``E_t`` (module docstring): ``iterations``
    steps (default ``options.iterations``), the first half with ARAP
    ``options.stiff_factor`` times stiffer, the image gradient refreshed every
    ``options.image_every`` steps.

    Parameters
    ----------
    x0 : (n, 3) float64 NumPy array
        Start control points (the previous frame's fit), in the unit box;
        also the ARAP rest shape.
    F : (m, 3) int64 NumPy array
        Control faces (one connectivity for the whole sequence).
    points, normals : (k, 3) float64 NumPy arrays or None
        The frame's oriented points, in the unit box; None when
        ``options.geometric`` is False.
    op : LimitOperator
        Limit samples of ``F`` for the distance terms (positions only suffice).
    image : PhotoTerm, RenderedTerm or None
        The frame's image term; None without one.
    options : SequenceOptions
        Weights, iteration counts, views per refresh, seed.
    frame : int
        Frame index: seeds the choice of views and the renders' samplers.
    lr : float
        Largest Adam step (unit box); the step starts from the warm start's
        IMLS residual, capped by ``lr``.
    progress : callable, optional
        Called as ``progress(done, total)`` after every iteration.
    rest : (n, 3) float64 NumPy array, optional
        The template: second ARAP rest shape, weight ``options.alpha_rest``.
    vertex_op : LimitOperator, optional
        One sample per control vertex (its limit point), for the data support
        of the image weights; without it the control points stand in.
    iterations : int, optional
        Steps for this frame (the first frame takes more).
    complete : bool, optional
        The data cover the whole surface (samples of a mesh frame): every
        control vertex counts as supported, and the images weigh by the
        data's roughness against the pixel width (module docstring).

    Returns
    -------
    V : (n, 3) float64 NumPy array
        Fitted control points, unit box.
    info : dict
        ``history`` (``geo`` energy per iteration and ``image`` loss, NaN
        between refreshes), ``time_render`` (seconds in the renders and their
        reverse passes), ``iterations``, ``image_scale`` (``k``), ``seen``
        (share of control vertices the data supports).

    Raises
    ------
    FitError
        If an energy is not finite (the message names the frame and the iteration).
    """
    import drjit as dr
    import mitsuba as mi

    from mi_loop.ad.control import ControlPoints
    from mi_loop.energies.arap import ARAP
    from mi_loop.energies.coverage import Coverage
    from mi_loop.energies.fold import fold_energy
    from mi_loop.energies.imls import IMLS

    n = len(x0)
    n_it = int(iterations or options.iterations)
    arap = ARAP(x0, F)                 # rest = previous frame's fit
    arap_rest = ARAP(rest, F) if rest is not None and options.alpha_rest > 0 else None
    imls = IMLS(points, normals, max_growths=options.reach) if options.geometric else None
    cover = Coverage(points, normals, tree=imls.tree) if options.geometric and options.cover > 0 else None
    alpha_t = dr.opaque(mi.Float, options.alpha / n)
    alpha_r = dr.opaque(mi.Float, options.alpha_rest / n)
    fold = None
    if options.fold > 0 and op.derivatives:   # the previous frame's limit normals: barrier against turning over
        n_prev = _sample_normals(op, x0)
        fold = (mi.Normal3f(n_prev.T.astype(np.float32)), dr.opaque(mi.Float, options.fold))
    rng = np.random.default_rng([options.seed, frame])
    if imls is not None:
        # Step from the residual of the warm start (as in static fitting), capped by lr.
        Q0 = op.positions(mi.Float(x0.ravel().astype(np.float32)))
        imls.update(np.array(Q0, dtype=np.float64).T, _sample_normals(op, x0))
        lr = float(np.clip(np.sqrt(float(imls.energy(Q0, reduce="mean")[0])) / 3.0, 1e-2 * lr, lr))
    opt = dr.opt.Adam(lr=lr, params={"x": mi.Float(x0.ravel().astype(np.float32))})
    use_image = options.image and image is not None
    noise, seen_weight, support_radius = None, options.seen, None
    if use_image and imls is not None and complete:   # a mesh frame: renders weigh by its roughness
        from mi_loop.mesh.points import noise_level

        noise = noise_level(imls.points, tree=imls.tree)
        seen_weight = options.seen * min(1.0, (noise / (0.5 * image.pixel_size())) ** 2)
        use_image = options.beta * seen_weight >= MIN_IMAGE_WEIGHT    # else the renders would move nothing
    elif use_image and imls is not None:              # full support within three data spacings
        P = imls.points[::max(1, len(imls.points) // 2000)]
        support_radius = 3.0 * float(np.median(imls.tree.query(P, k=2)[0][:, 1]))
    smooth = None
    if use_image and options.lam > 0:
        from mi_loop.fitting.largesteps import SmoothParameterisation

        smooth = SmoothParameterisation(F, n, options.lam)
    order = []
    history = {"geo": [], "image": []}
    t_render, k_scale, g_image, weights, seen = 0.0, None, None, None, 1.0
    for it in range(n_it):
        x = ControlPoints(opt["x"])       # shared by ARAP and the limit operator
        Vn = x.numpy()
        # Stiff-to-soft: the first half of the iterations weigh ARAP (relative
        # to the previous frame) by stiff_factor, so parts that moved far (thin
        # horns, legs) follow the bulk as near-rigid pieces instead of snapping
        # onto the nearest surface; the second half fits details.
        stiff = it < n_it // 2 and options.stiff_factor > 1
        E = (alpha_t * options.stiff_factor if stiff else alpha_t) * arap.energy(x, arap.rotations(Vn))
        if arap_rest is not None:
            E = E + alpha_r * arap_rest.energy(x, arap_rest.rotations(Vn))
        if fold is not None:       # limit normals turned by more than 60 degrees since the previous frame
            E = E + fold[1] * fold_energy(op.normals(x), fold[0])
        refresh = it % 10 == 0
        if imls is not None:
            Q = op.positions(x)
            if refresh:
                Qn = np.array(Q, dtype=np.float64).T
                Nq = _sample_normals(op, Vn)
                imls.update(Qn, Nq)
                if cover is not None:
                    cover.update(Qn, Nq)
            E = E + imls.energy(Q, reduce="mean")
            if cover is not None:
                E = E + options.cover * cover.energy(Q)
        geo = float(E[0])
        if not np.isfinite(geo):
            raise FitError(f"fit_frame(): expected a finite energy, got geometric {geo} at frame {frame}, "
                           f"iteration {it} (the optimisation diverged)")
        dr.backward(E)
        loss = np.nan
        if use_image and it % options.image_every == 0:
            if refresh or weights is None:
                if complete and imls is not None:   # a mesh frame: the data see every part of the surface
                    weights, s = np.full(n, options.beta * seen_weight), np.ones(n)
                else:
                    weights, s = _image_weights(Vn, vertex_op, imls, support_radius, seen_weight, options)
                seen = float(np.mean(s > 0.5)) if s is not None else 0.0
            t = time.perf_counter()
            if len(order) < options.views_per_iteration:
                order += rng.permutation(image.n_views).tolist()
            ids, order = order[:options.views_per_iteration], order[options.views_per_iteration:]
            g_image, loss = image.gradient(Vn, ids, seed=frame * 1000 + it + 100_000 * options.seed)
            t_render += time.perf_counter() - t
            if smooth is not None:         # Sobolev gradient: the render noise averaged over neighbourhoods
                g_image = smooth.gradient(g_image)
            if not (np.isfinite(loss) and np.isfinite(g_image).all()):
                raise FitError(f"fit_frame(): expected a finite image loss, got {loss} at frame {frame}, "
                               f"iteration {it} (the optimisation diverged)")
            if k_scale is None:
                k_scale = _image_scale(np.asarray(dr.grad(opt["x"]), dtype=np.float64).reshape(-1, 3),
                                       g_image, s, options)
        if g_image is not None:
            g = np.asarray(dr.grad(opt["x"]), dtype=np.float64).reshape(-1, 3)
            g += (k_scale * weights)[:, None] * g_image
            dr.set_grad(opt["x"], mi.Float(g.astype(np.float32).ravel()))
        history["geo"].append(geo)
        history["image"].append(loss)
        opt.step()
        if progress is not None:
            progress(it + 1, n_it)
    V = np.array(opt["x"], dtype=np.float64).reshape(-1, 3)
    return V, {"history": history, "time_render": t_render, "iterations": n_it,
               "image_scale": float(k_scale) if k_scale is not None else None, "seen": float(seen),
               "noise": noise, "seen_weight": float(seen_weight)}


def _sample_normals(op, Vn):
    """Unit limit normals at the operator's samples (NumPy), or None if it has no derivative rows."""
    import drjit as dr
    import mitsuba as mi

    if not op.derivatives:
        return None
    with dr.suspend_grad():
        return np.array(op.normals(mi.Float(np.asarray(Vn, dtype=np.float32).ravel())), dtype=np.float64).T


def _image_weights(Vn, vertex_op, imls, radius: float, w: float, options: SequenceOptions):
    """Per-vertex image weights ``beta (w + (1 - w)(1 - s_i))`` and the supports ``s`` (None: images only)."""
    import mitsuba as mi

    if imls is None:                    # images only: the same weight everywhere
        return np.full(len(Vn), options.beta), None
    Nq = None
    if vertex_op is not None:
        Q = np.array(vertex_op.positions(mi.Float(Vn.ravel().astype(np.float32))), dtype=np.float64).T
        Nq = _sample_normals(vertex_op, Vn)
    else:
        Q = Vn
    s = support(Q, imls.tree, radius, Nq, imls.normals if Nq is not None else None)
    return options.beta * (w + (1.0 - w) * (1.0 - s)), s


def _image_scale(g_geo, g_image, s, options: SequenceOptions) -> float:
    """``k``: RMS of the geometric gradient over supported vertices / RMS of the image gradient."""
    if not options.geometric:
        return 1.0
    supported = (s > 0.5) & (options.seen < 1)     # with seen 1 the weights do not tell them apart
    rows = g_geo[supported] if supported.any() else g_geo
    a = float(np.sqrt(np.mean(np.sum(rows ** 2, axis=1))))
    b = float(np.sqrt(np.mean(np.sum(g_image ** 2, axis=1))))
    return a / b if b > 0 else 0.0
