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

IMAGE_MODES = ("shading", "silhouette")
LOSSES = ("l1", "l2")


def rig_views(n_views: int):
    """``n_views`` (azimuth, elevation) pairs in degrees spread over the whole sphere.

    Fibonacci-sphere directions (y up), so every part of the subject is seen.
    """
    if n_views < 1:
        raise ValueError(f"rig_views(): expected at least one view, got {n_views}")
    i = np.arange(n_views) + 0.5
    y = 1.0 - 2.0 * i / n_views
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    elevation = np.degrees(np.arcsin(np.clip(y, -1, 1)))
    azimuth = np.degrees(phi) % 360.0
    return [(float(a), float(e)) for a, e in zip(azimuth, elevation)]


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


class Renderer:
    """Prediction scene (``loop_subdiv``, ``direct_projective``) and target renders.

    Parameters
    ----------
    V0, F : numpy arrays
        Control mesh (normalised units) whose limit surface is rendered.
    bbox : ((3,), (3,))
        Box framing the subject for the whole sequence (fixed cameras).
    options : SequenceOptions
    """

    def __init__(self, V0, F, bbox, options: SequenceOptions):
        import mitsuba as mi

        from .plugin import create
        from .render import scene_dict

        self.options = options
        self.views = rig_views(options.views)
        self.bbox = bbox
        self._bsdf = self._material()
        shape = create(V0, F, level=options.level, bsdf=mi.load_dict(self._bsdf))
        self.scene = mi.load_dict(self._scene_dict(shape, {"type": "direct_projective", "sppi": 0}))
        self.params = mi.traverse(self.scene)
        self.key = next(k for k in self.params.keys() if k.endswith("control_points"))
        self.params.keep([self.key])

    def _material(self):
        if self.options.mode == "silhouette":   # black object against a white environment
            return {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}}
        return {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.6, 0.6, 0.6]}}

    def _scene_dict(self, shape, integrator):
        from .render import scene_dict

        desc = scene_dict(shape, views=self.views, resolution=self.options.resolution,
                          integrator=integrator, sample_border=True, bbox=self.bbox)
        if self.options.mode == "silhouette":
            desc.pop("key_light", None)
        return desc

    def targets(self, V, F, normals=None):
        """Render a target frame (a triangle mesh) from every view; list of ``mi.TensorXf``."""
        import drjit as dr
        import mitsuba as mi

        from .plugin import plain_mesh

        mesh = plain_mesh(V, F, normals=normals, bsdf=mi.load_dict(self._bsdf))
        scene = mi.load_dict(self._scene_dict(mesh, {"type": "direct"}))
        images = []
        for k in range(len(self.views)):
            img = mi.render(scene, spp=self.options.target_spp, seed=10_000 + k, sensor=k)
            dr.eval(img)
            images.append(img)
        return images

    def view_loss(self, x, k: int, targets, seed: int):
        """Image loss of control points ``x`` in view ``k`` (differentiable, ``mi.Float (1)``)."""
        import drjit as dr
        import mitsuba as mi

        from .operator import forget_unravelled

        forget_unravelled()   # this view's geometry gets a graph of its own
        self.params[self.key] = x
        self.params.set_dirty(self.key)
        self.params.update()
        img = mi.render(self.scene, self.params, spp=self.options.spp,
                        seed=int(seed) * 997 + int(k), sensor=int(k))
        diff = img - targets[k]
        term = dr.abs(diff) if self.options.loss == "l1" else dr.square(diff)
        return dr.mean(term.array)

    def backward(self, x, view_ids, targets, seed: int, weight=1.0) -> float:
        """Accumulate ``weight * mean_k l_k`` gradients into ``x``; return the mean loss.

        One backward pass per view: Mitsuba's differentiable render releases
        the geometry's AD graph (vertex positions back to ``x``) during its
        reverse pass, so a second view in the same pass would stop at the
        vertex positions (checked in ``tests/test_sequence.py``).
        """
        import drjit as dr

        total = 0.0
        for k in view_ids:
            L = self.view_loss(x, k, targets, seed)
            total += float(L[0])
            dr.backward(L * (weight / len(view_ids)))
        return total / len(view_ids)

    def loss(self, x, view_ids, targets, seed: int):
        """Mean image loss over ``view_ids`` (value only; see :meth:`backward` for gradients)."""
        import drjit as dr

        with dr.suspend_grad():
            return sum(float(self.view_loss(x, k, targets, seed)[0]) for k in view_ids) / len(view_ids)


def vertex_normals(V, F):
    """Area-weighted vertex normals of a triangle mesh, ``(n, 3)``."""
    Fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    N = np.zeros_like(V)
    for c in range(3):
        np.add.at(N, F[:, c], Fn)
    return N / np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-30)


def fit_frame(x0, F, points, normals, op, targets, renderer, options: SequenceOptions,
              frame: int, lr: float, progress=None):
    """Fit one frame from the control points ``x0`` (normalised ``(n, 3)``); returns ``(V, info)``.

    ``targets`` are the target renders (None without the image term).
    """
    import drjit as dr
    import mitsuba as mi

    from .arap import ARAP
    from .coverage import Coverage
    from .imls import IMLS

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
