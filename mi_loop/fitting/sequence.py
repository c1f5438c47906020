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
from dataclasses import dataclass

import numpy as np

from mi_loop.render.multiview import IMAGE_MODES, LOSSES

@dataclass
class SequenceOptions:
    """Parameters of :func:`fit_frame` (defaults tuned on 2 CPU cores)."""

    alpha: float = 0.01          # ARAP weight
    beta: float = 1.0            # image-loss weight
    views: int = 20              # cameras in the rig
    views_per_iteration: int = 2
    resolution: int = 96
    spp: int = 4                 # samples per pixel of the differentiable renders
    target_spp: int = 32         # samples per pixel of the target renders
    level: int = 1               # tessellation level of the rendered limit surface
    loss: str = "l1"
    mode: str = "shading"        # or 'silhouette'
    geometric: bool = True       # IMLS + ARAP terms (False: image only, ARAP kept)
    image: bool = True           # image term
    geo_iterations: int = 200    # geometric iterations per frame (first half with stiff ARAP)
    joint_iterations: int = 8    # iterations with the image term per frame
    joint_lr_scale: float = 0.05  # step of the joint iterations relative to the geometric ones
    stiff_factor: float = 100.0  # ARAP weight factor for the first half of the geometric iterations
    cover: float = 3.0           # weight of the coverage term (data points pull their nearest samples)
    seed: int = 0

    def __post_init__(self):
        for name in ("alpha", "beta", "cover", "stiff_factor"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"SequenceOptions: {name} must be a finite number >= 0, got {value}")
        if not (np.isfinite(self.joint_lr_scale) and self.joint_lr_scale > 0):
            raise ValueError(f"SequenceOptions: joint_lr_scale must be a finite number > 0, "
                             f"got {self.joint_lr_scale}")
        if self.loss not in LOSSES:
            raise ValueError(f"SequenceOptions: loss must be one of {LOSSES}, got {self.loss!r}")
        if self.mode not in IMAGE_MODES:
            raise ValueError(f"SequenceOptions: mode must be one of {IMAGE_MODES}, got {self.mode!r}")
        if not 1 <= self.views_per_iteration <= self.views:
            raise ValueError(f"SequenceOptions: views_per_iteration must be in [1, views={self.views}], "
                             f"got {self.views_per_iteration}")
        if not (self.geometric or self.image):
            raise ValueError("SequenceOptions: geometric and image terms are both off; nothing to fit")

    @property
    def rig(self):
        """The :class:`~mi_loop.render.multiview.RigOptions` of the image term."""
        from mi_loop.render.multiview import RigOptions

        return RigOptions(views=self.views, resolution=self.resolution, spp=self.spp,
                          target_spp=self.target_spp, level=self.level, loss=self.loss, mode=self.mode)


def fit_frame(x0, F, points, normals, op, targets, renderer, options: SequenceOptions,
              frame: int, lr: float, progress=None):
    """Fit one frame from the control points ``x0`` (normalised ``(n, 3)``); returns ``(V, info)``.

    ``targets`` are the target renders (None without the image term).
    """
    import drjit as dr
    import mitsuba as mi

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
        x = opt["x"]
        Vn = np.array(x, dtype=np.float64).reshape(-1, 3)
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
            raise FloatingPointError(f"fit_frame(): non-finite energy at frame {frame}, iteration {it}")
        history["geo"].append(geo)
        history["image"].append(image)
        opt.step()
        if progress is not None:
            progress(it + 1, n_geo + n_joint)
    V = np.array(opt["x"], dtype=np.float64).reshape(-1, 3)
    return V, {"history": history, "time_render": t_render, "iterations": n_geo + n_joint}
