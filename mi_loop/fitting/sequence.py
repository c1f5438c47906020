"""Frame-by-frame fitting of one control mesh to a deforming sequence, with multi-view rendering.

Per frame ``t`` the control points minimise

    E_t = mean_j f_t(Q_j)^2 + alpha E_arap(V; V_{t-1}) / n + beta l_image,

``f_t`` the IMLS function of frame ``t``, ARAP relative to the previous frame's
fit (warm start), and ``l_image`` the mean L1 (or L2) pixel difference over a
random subset of the rig's views between ``direct_projective`` renders of the
limit surface (the ``loop_subdiv`` shape, exact limit normals) and renders of
the target frame. Gradients of all terms accumulate into the same control
points through the renderer, the limit operator and both geometric energies
(one reverse pass for the geometric terms and one per rendered view, because
Mitsuba's render releases the geometry's graph in its reverse pass). No file
I/O here.
"""
from __future__ import annotations

import time

import numpy as np

from mi_loop.errors import FitError
from mi_loop.fitting.options import SequenceOptions

__all__ = ["SequenceOptions", "fit_frame"]   # SequenceOptions lives in mi_loop.fitting.options


def fit_frame(x0, F, points, normals, op, targets, renderer, options: SequenceOptions,
              frame: int, lr: float, progress=None):
    """Fit the control points of one frame, warm-started from the previous frame's ``x0``.

    Adam on ``E_t`` (module docstring): ``options.geo_iterations`` steps of
    the geometric terms, then ``options.joint_iterations`` steps that add the
    image term over ``options.views_per_iteration`` random views per step.

    Parameters
    ----------
    x0 : (n, 3) float64 NumPy array
        Start control points (the previous frame's fit), in normalised units;
        also the ARAP rest shape.
    F : (m, 3) int64 NumPy array
        Control faces (one connectivity for the whole sequence).
    points, normals : (k, 3) float64 NumPy arrays or None
        The frame's oriented points, normalised like ``x0``; None when
        ``options.geometric`` is False.
    op : LimitOperator
        Limit samples of ``F`` for the distance terms (Dr.Jit; positions only suffice).
    targets : list of mi.TensorXf or None
        Target renders of every view (:meth:`Renderer.targets
        <mi_loop.render.multiview.Renderer.targets>`); None without the image term.
    renderer : Renderer or None
        The sequence's renderer (fixed cameras); None without the image term.
    options : SequenceOptions
        Weights, iteration counts, views per step, seed.
    frame : int
        Frame index: seeds the choice of views and the renders' samplers.
    lr : float
        Largest Adam step (normalised units); the step starts from the warm
        start's IMLS residual, capped by ``lr``.
    progress : callable, optional
        Called as ``progress(done, total)`` after every iteration.

    Returns
    -------
    V : (n, 3) float64 NumPy array
        Fitted control points, normalised units.
    info : dict
        ``history`` (``geo`` and ``image`` energy per iteration; ``image`` is
        NaN in the geometric steps), ``time_render`` (seconds in the reverse
        renders), ``iterations``.

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
    from mi_loop.energies.imls import IMLS

    n = len(x0)
    arap = ARAP(x0, F)                 # rest = previous frame's fit
    imls = IMLS(points, normals) if options.geometric else None
    cover = Coverage(points, normals, tree=imls.tree) if options.geometric and options.cover > 0 else None
    alpha_t = dr.opaque(mi.Float, options.alpha / n)
    rng = np.random.default_rng([options.seed, frame])
    if imls is not None:
        # Step from the residual of the warm start (as in static fitting), capped by lr.
        Q0 = op.positions(mi.Float(x0.ravel().astype(np.float32)))
        imls.update(np.array(Q0, dtype=np.float64).T)
        lr = float(np.clip(np.sqrt(float(imls.energy(Q0, reduce="mean")[0])) / 3.0, 1e-2 * lr, lr))
    opt = dr.opt.Adam(lr=lr, params={"x": mi.Float(x0.ravel().astype(np.float32))})
    use_image = options.image and targets is not None
    n_geo = options.geo_iterations if options.geometric else 0
    n_joint = options.joint_iterations if use_image else 0
    history = {"geo": [], "image": []}
    t_render = 0.0
    for it in range(n_geo + n_joint):
        x = ControlPoints(opt["x"])       # shared by ARAP, the limit operator and the renders
        Vn = x.numpy()
        # Stiff-to-soft: the first half of the geometric iterations weigh ARAP
        # (relative to the previous frame) by stiff_factor, so parts that moved
        # far (thin horns, legs) follow the bulk as near-rigid pieces instead of
        # snapping onto the nearest surface; the second half fits details.
        stiff = it < n_geo // 2 and options.stiff_factor > 1
        E = (alpha_t * options.stiff_factor if stiff else alpha_t) * arap.energy(x, arap.rotations(Vn))
        if imls is not None:
            Q = op.positions(x)
            if it % 10 == 0:
                Qn = np.array(Q, dtype=np.float64).T
                imls.update(Qn)
                if cover is not None:
                    cover.update(Qn)
            E = E + imls.energy(Q, reduce="mean")
            if cover is not None:
                E = E + options.cover * cover.energy(Q)
        geo = float(E[0])
        image = np.nan
        if it == n_geo and n_geo:
            opt.set_learning_rate(options.joint_lr_scale * lr)   # noisy image gradients: smaller steps
        dr.backward(E)
        if it >= n_geo:
            t = time.perf_counter()
            views = rng.choice(len(renderer.views), options.views_per_iteration, replace=False)
            image = renderer.backward(x, views, targets, seed=frame * 1000 + it, weight=options.beta)
            t_render += time.perf_counter() - t
        if not np.isfinite(geo) or not np.isfinite(image if it >= n_geo else 0.0):
            raise FitError(f"fit_frame(): expected a finite energy, got geometric {geo}, image {image} "
                           f"at frame {frame}, iteration {it} (the optimisation diverged)")
        history["geo"].append(geo)
        history["image"].append(image)
        opt.step()
        if progress is not None:
            progress(it + 1, n_geo + n_joint)
    V = np.array(opt["x"], dtype=np.float64).reshape(-1, 3)
    return V, {"history": history, "time_render": t_render, "iterations": n_geo + n_joint}
