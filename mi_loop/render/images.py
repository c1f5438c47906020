"""The differentiable image loss of a ``loop_subdiv`` shape against views: photos or rendered targets.

:class:`ImageRenderer` puts the limit surface of a control mesh, with a
per-control-vertex albedo (the diffuse :func:`~mi_loop.render.plugin.albedo_bsdf`;
a constant albedo is a plain grey or black material), in a scene with one
Mitsuba sensor per view (:func:`mi_loop.render.cameras.sensor_dict`, the
camera exactly) and the given emitters, and compares each render with its
target: mean L1 or L2 over the pixels of linear RGB. Gradients flow to the
control points (through silhouettes and shading, with ``direct_projective`` or
``prb_projective``) and to the albedo.

Targets. A view (:class:`mi_loop.io.View`) is a camera, linear RGB and a mask.
A photo shows its own background, the renders show the emitters, so each
target is the view composited over a render of the emitters alone,
``T = mask * rgb + (1 - mask) * B`` (:func:`~mi_loop.render.captures.background`):
inside the mask the shading is compared, across its border the silhouette. A
target rendered in the same emitters (:func:`~mi_loop.render.captures.render_targets`)
already shows them wherever the mesh
leaves a pixel uncovered, in whole or in part (at a pixel a fraction ``a``
covered, Mitsuba's ``hdrfilm`` stores ``a S + (1 - a) B`` in RGB and ``a`` in
alpha), so its mask is all ones and ``T`` is the render itself.

Weights. Not every pixel of a photo's mask can be believed: each view's loss
is the mean over all pixels of ``w |R - T|`` (or ``w (R - T)^2``), ``w`` the
weights of :func:`~mi_loop.render.mask_trust.pixel_weights`: 0 on uncertain
mask pixels off the mask's edge (soft masks, JPEG ringing), 0 on foreground
within two pixels of the frame or of pixels an undistorted photo did not see
(the subject continues there: a surface that leaves the frame is not pulled
back in), ``View.valid`` elsewhere, 1 without it. A view whose weights are
all 1 (binary or antialiased masks inside the frame: synthetic captures,
rendered targets) is compared unweighted, exactly as before.

Lighting. Given a :class:`~mi_loop.render.lighting.Lighting` (lighting the
photos do not state: spherical-harmonic shading and a gain per photo), the
surface is not lit by the emitters: its radiance towards view ``k`` is
``g_k * albedo * s(n)`` at every tessellation vertex, shown through Mitsuba as
the shape's emission at path depth 1 (``prb_projective``, ``max_depth`` 1), and
the emitters are only the backdrop the masks composite over. The gradients of
each view's loss then also reach the lighting's ``coefficients`` and ``log_gain``
where they carry gradients.

Seeds. Every render of view ``k`` under the seed ``s`` of a call uses the
sampler seed :func:`~mi_loop.render.captures.view_seed` ``(s, k)`` (the seed tree, one level down):
:meth:`~ImageRenderer.render`, :meth:`~ImageRenderer.view_loss`,
:meth:`~ImageRenderer.backward` and :meth:`~ImageRenderer.losses` see the
same samples for the same ``(s, k)``, and the views of one call see different ones.
"""
from __future__ import annotations

import numpy as np

from mi_loop.ad.control import ControlPoints
from mi_loop.ad.threads import one_thread
from mi_loop.errors import fail
from mi_loop.render.captures import background, camera_scene, check_albedo, check_count, check_views, view_seed
from mi_loop.render.lighting import Lighting
from mi_loop.render.mask_trust import pixel_weights
from mi_loop.render.plugin import RADIANCE_ATTRIBUTE, albedo_bsdf, create

__all__ = ["INTEGRATORS", "LOSSES", "ImageRenderer"]

#: Integrators whose gradients include silhouettes (see :mod:`mi_loop.render.plugin`).
INTEGRATORS = ("direct_projective", "prb_projective")
#: Pixel losses of :class:`ImageRenderer`.
LOSSES = ("l1", "l2")


class ImageRenderer:
    """Differentiable renders of a Loop surface with albedo, against views (photos or rendered targets).

    Parameters
    ----------
    V : (n, 3) float NumPy array
        Control points.
    F : (m, 3) int NumPy array
        Control faces.
    views : sequence of mi_loop.io.capture.View
        The targets and their cameras, at the resolution to render (photos, or
        :func:`~mi_loop.render.captures.render_targets`).
    emitters : list of dict or mi.Emitter
        The lighting; with ``lighting``, the backdrop only (module docstring).
    albedo : (n, 3) float NumPy array
        Per-control-vertex linear RGB in [0, 1], rendered when a call passes no ``c``.
    level : int
        Tessellation level of the rendered limit surface, >= 0.
    spp : int
        Samples per pixel of the differentiable renders, >= 1.
    integrator : {'direct_projective', 'prb_projective'}
        Mitsuba integrator (``sppi`` 0).
    loss : {'l1', 'l2'}
        Mean absolute or mean squared difference over pixels and channels.
    deterministic : bool
        Run each reverse render on one LLVM thread (:func:`mi_loop.ad.threads.one_thread`):
        Mitsuba scatters the image gradient into the vertex buffer with atomic
        adds, whose order otherwise changes from run to run. Slower.
    lighting : Lighting, optional
        Estimated lighting (module docstring); its ``n_views`` must be the
        number of views. ``integrator`` is then ``prb_projective`` at depth 1.
    highlights : float, optional
        ``t > 0``: a pixel inside a view's mask (mask 1) whose target exceeds
        ``t`` times the render plus 0.02, channel by channel, is left out of
        that view's loss (a highlight the diffuse model cannot show); 0: off.

    Attributes
    ----------
    views : list of mi_loop.io.capture.View
    targets : list of mi.TensorXf (h, w, 3)
        The views composited over the emitters' background (module docstring).
    weights : list of mi.TensorXf (h, w, 3) or None
        Per view, its pixels' weights in the loss (module docstring), None where all are 1.
    lighting : Lighting or None
        The estimated lighting, whose coefficients and gains the renders read at each call.
    shape : mi.Mesh
        The ``loop_subdiv`` shape.

    Raises
    ------
    ValueError
        ``V`` not of shape (n, 3), ``albedo`` not of shape (n, 3) or outside
        [0, 1], no views, an unknown integrator or loss, ``level < 0``, ``spp < 1``;
        an invalid control mesh (:func:`mi_loop.render.plugin.create`); a
        lighting for another number of views.
    TypeError
        A view that is not a :class:`mi_loop.io.View`; a lighting that is not a :class:`Lighting`.

    Notes
    -----
    Arguments ``x`` and ``c`` of the methods are flat ``mi.Float`` of length
    ``3 n`` (xyz / rgb interleaved; ``x`` may be a :class:`~mi_loop.ad.control.ControlPoints`),
    with or without gradients; ``c = None`` renders the albedo last set.
    """

    def __init__(self, V, F, views, emitters, *, albedo, level: int, spp: int,
                 integrator: str = "direct_projective", loss: str = "l1", deterministic: bool = False,
                 lighting: Lighting | None = None, highlights: float = 0.0):
        import mitsuba as mi

        func = "ImageRenderer"
        V = np.asarray(V, dtype=np.float64)
        if V.ndim != 2 or V.shape[1] != 3:
            fail(func, "control points V of shape (n, 3)", f"shape {V.shape}")
        A = check_albedo(albedo, len(V), func)
        self.views = check_views(views, func)
        if integrator not in INTEGRATORS:
            fail(func, f"integrator to be one of {INTEGRATORS}", repr(integrator))
        if loss not in LOSSES:
            fail(func, f"loss to be one of {LOSSES}", repr(loss))
        if not np.isfinite(highlights) or highlights < 0:
            fail(func, "highlights, a factor >= 0 (0: off)", highlights)
        self.highlights = float(highlights)
        level, self.spp = check_count(level, func, "level", 0), check_count(spp, func, "spp", 1)
        self.loss, self.deterministic, self.emitters = loss, bool(deterministic), list(emitters)
        integrator = {"type": integrator, "sppi": 0}
        self.lighting = lighting
        if lighting is not None:
            if not isinstance(lighting, Lighting):
                raise TypeError(f"{func}(): expected lighting to be a mi_loop.render.lighting.Lighting, "
                                f"got {type(lighting).__name__}")
            if lighting.n_views != len(self.views):
                fail(func, f"a lighting of {len(self.views)} views (one gain per view)", f"{lighting.n_views}")
            integrator = {"type": "prb_projective", "max_depth": 1, "sppi": 0}
        self.shape = create(V, F, level=level, albedo=A, bsdf=mi.load_dict(albedo_bsdf()),
                            emission=lighting is not None)
        self.scene = camera_scene(self.shape, self.cameras, self.emitters, integrator=integrator, spp=self.spp)
        self.params = mi.traverse(self.scene)
        names = ("control_points", "control_albedo") + (() if lighting is None else (RADIANCE_ATTRIBUTE,))
        self.keys = {name: next(k for k in self.params.keys() if k.endswith(name)) for name in names}
        self.params.keep(list(self.keys.values()))
        self._backgrounds = None
        self._composite()

    @property
    def cameras(self) -> list:
        """The views' cameras, in order (one sensor each)."""
        return [v.camera for v in self.views]

    @property
    def n_views(self) -> int:
        """Number of views."""
        return len(self.views)

    def _composite(self) -> None:
        import mitsuba as mi

        if self._backgrounds is None and any((v.mask < 1).any() for v in self.views):
            self._backgrounds = background(self.cameras, self.emitters)
        self.targets, self.weights, self._inside = [], [], []
        for k, view in enumerate(self.views):
            a = view.mask[..., None]
            T = view.rgb if (a == 1).all() else a * view.rgb + (1.0 - a) * self._backgrounds[k]
            self.targets.append(mi.TensorXf(np.ascontiguousarray(T, dtype=np.float32)))
            w = pixel_weights(view.mask, view.valid)
            self.weights.append(None if w is None else mi.TensorXf(np.repeat(w[..., None], 3, axis=2)))
            if self.highlights > 0:
                self._inside.append(mi.Bool(np.repeat(view.mask[..., None] >= 1.0, 3, axis=2).ravel()))

    def set_photos(self, views) -> bool:
        """Take new targets from the same cameras (a sequence's next frame); False if the cameras differ.

        The scene (and the backgrounds) are kept, so only the targets are
        recomposited. With other cameras nothing changes and a new renderer is
        needed.

        Raises
        ------
        ValueError, TypeError
            No views, a view that is not a :class:`mi_loop.io.View`.
        """
        views = check_views(views, "ImageRenderer.set_photos")
        if [v.camera for v in views] != self.cameras:
            return False
        self.views = views
        self._composite()
        return True

    def _set(self, x, c, k: int) -> None:
        import drjit as dr

        for name, value in (("control_points", x), ("control_albedo", c)):
            if value is not None:        # marked dirty: the same variable again must rebuild its graph
                self.params[self.keys[name]] = value.flat if isinstance(value, ControlPoints) else value
                self.params.set_dirty(self.keys[name])
        self.params.update()
        if self.lighting is not None:    # view k's radiance, from the limit albedo and normals just computed
            L = self.lighting.radiance(self.shape.limit_albedo, self.shape.limit_normals, k)
            self.params[self.keys[RADIANCE_ATTRIBUTE]] = dr.ravel(L)
            self.params.update()

    def _check_view(self, k, func: str) -> int:
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k < self.n_views:
            fail(func, f"a view index in [0, {self.n_views})", k)
        return int(k)

    def render(self, x, c, k: int, *, seed: int, spp: int | None = None):
        """Render view ``k`` with control points ``x`` and albedo ``c`` (class Notes).

        Parameters
        ----------
        x : mi.Float (3n) or ControlPoints
            Control points (gradients kept).
        c : mi.Float (3n) or None
            Albedo (gradients kept); None: the albedo last set.
        k : int
            View, in ``[0, n_views)``.
        seed : int
            Seed of the call; the sampler's is :func:`view_seed` ``(seed, k)``.
        spp : int, optional
            Samples per pixel (default: the renderer's), >= 1.

        Returns
        -------
        mi.TensorXf (h, w, 3)
            Linear RGB, differentiable.

        Raises
        ------
        ValueError
            ``k`` out of range, ``spp < 1``.
        """
        import mitsuba as mi

        k = self._check_view(k, "ImageRenderer.render")
        spp = self.spp if spp is None else check_count(spp, "ImageRenderer.render", "spp", 1)
        self._set(x, c, k)
        return mi.render(self.scene, self.params, spp=spp, seed=view_seed(seed, k), sensor=k)

    def view_loss(self, x, c, k: int, *, seed: int, spp: int | None = None):
        """Loss (L1 or L2) between the render of view ``k`` and its target; ``mi.Float (1)``, differentiable.

        The mean over all pixels and channels, each pixel weighted by
        ``weights[k]`` where the view has weights (module docstring), without
        the highlights where the renderer leaves them out. Arguments as in
        :meth:`render`.
        """
        import drjit as dr

        R, T = self.render(x, c, k, seed=seed, spp=spp), self.targets[int(k)]
        diff = R - T
        error = dr.abs(diff) if self.loss == "l1" else dr.square(diff)
        if self.weights[int(k)] is not None:
            error = error * self.weights[int(k)]
        error = error.array
        if self.highlights > 0:
            bright = self._inside[int(k)] & (T.array > self.highlights * dr.detach(R.array) + 0.02)
            error = dr.select(bright, 0.0, error)
        return dr.mean(error)

    def backward(self, x, c, view_ids, *, seed: int, weight: float = 1.0) -> list:
        """Accumulate the gradients of ``weight * mean_k loss_k`` into ``x`` and ``c``; return each ``loss_k``.

        One reverse pass per view: Mitsuba's differentiable render releases the
        geometry's AD graph (vertex positions back to ``x``) during its reverse
        pass, so a second view in the same pass would stop at the vertex
        positions; each view therefore rebuilds the geometry from ``x`` (and the
        colours from ``c``). Either may be without gradients (``c`` may be None).

        Parameters
        ----------
        x, c :
            As in :meth:`render`.
        view_ids : sequence of int
            Views, at least one, each in ``[0, n_views)``.
        seed : int
            Seed of the call (view ``k`` renders with :func:`view_seed` ``(seed, k)``).
        weight : float, optional
            Factor of the accumulated gradients (not of the returned losses).

        Returns
        -------
        list of float
            ``loss_k`` per entry of ``view_ids``, in order.
        """
        import drjit as dr

        view_ids = list(view_ids)
        if not view_ids:
            fail("ImageRenderer.backward", "at least one view id", "none")
        for k in view_ids:
            self._check_view(k, "ImageRenderer.backward")
        losses = []
        for k in view_ids:
            loss = self.view_loss(x, c, k, seed=seed)
            losses.append(float(loss[0]))
            with one_thread(self.deterministic):
                dr.backward(loss * (weight / len(view_ids)))
        return losses

    def losses(self, x, c, view_ids=None, *, seed: int, spp: int | None = None) -> list:
        """Loss of each view of ``view_ids`` (default: all), values only; arguments as in :meth:`render`."""
        import drjit as dr

        ids = range(self.n_views) if view_ids is None else [self._check_view(k, "ImageRenderer.losses")
                                                            for k in view_ids]
        with dr.suspend_grad():
            return [float(self.view_loss(x, c, k, seed=seed, spp=spp)[0]) for k in ids]
