"""The image loss of a ``loop_subdiv`` shape against calibrated photos (shape and albedo gradients).

:class:`PhotoRenderer` puts the limit surface of a control mesh, with a
per-control-vertex albedo, in a scene with one Mitsuba sensor per photo
(:func:`mi_loop.render.cameras.sensor_dict`, the NeRF camera exactly) and the
capture's emitters, and compares each render with its photo: mean L1 over the
pixels of linear RGB. Photos show their own background; the renders show the
emitters (the environment). So each target is the photo composited over a
render of the emitters alone, ``T = mask * photo + (1 - mask) * B``: inside the
mask the shading is compared, across its border the silhouette. Gradients
flow to the control points (through silhouettes and shading, with
``direct_projective`` or ``prb_projective``) and to the albedo.

Superseded by :class:`mi_loop.render.images.ImageRenderer` (which also takes
rendered targets); :data:`INTEGRATORS` lives there, :func:`background` and
:func:`render_views` in :mod:`mi_loop.render.captures`, re-exported here.
"""
from __future__ import annotations

import numpy as np

from mi_loop.ad.threads import one_thread
from mi_loop.render.captures import background, camera_scene, render_views
from mi_loop.render.images import INTEGRATORS
from mi_loop.render.plugin import albedo_bsdf, create

__all__ = ["INTEGRATORS", "PhotoRenderer", "background", "render_views"]


class PhotoRenderer:
    """Differentiable renders of a Loop surface with albedo, against photos.

    Parameters
    ----------
    V : (n, 3) float NumPy array
        Control points.
    F : (m, 3) int NumPy array
        Control faces.
    albedo : (n, 3) float NumPy array
        Per-control-vertex linear RGB in [0, 1].
    views : sequence of mi_loop.io.capture.View
        The photos and their cameras, at the resolution to render.
    emitters : list of dict or mi.Emitter
        The capture's lighting.
    level : int
        Tessellation level of the rendered limit surface.
    spp : int
        Samples per pixel of the differentiable renders.
    integrator : {'direct_projective', 'prb_projective'}
        Mitsuba integrator (``sppi`` 0).
    deterministic : bool
        Run each reverse render on one LLVM thread (see :mod:`mi_loop.ad.threads`).

    Attributes
    ----------
    targets : list of mi.TensorXf (h, w, 3)
        Photos composited over the emitters' background (module docstring).
    """

    def __init__(self, V, F, albedo, views, emitters, *, level: int, spp: int,
                 integrator: str = "direct_projective", deterministic: bool = False):
        import mitsuba as mi

        if integrator not in INTEGRATORS:
            raise ValueError(f"PhotoRenderer(): expected integrator to be one of {INTEGRATORS}, got {integrator!r}")
        self.views, self.spp, self.deterministic = list(views), int(spp), bool(deterministic)
        cameras = [v.camera for v in self.views]
        self.shape = create(V, F, level=level, albedo=albedo, bsdf=mi.load_dict(albedo_bsdf()))
        self.scene = camera_scene(self.shape, cameras, emitters, integrator={"type": integrator, "sppi": 0},
                                  spp=spp)
        self.params = mi.traverse(self.scene)
        self.keys = {name: next(k for k in self.params.keys() if k.endswith(name))
                     for name in ("control_points", "control_albedo")}
        self.params.keep(list(self.keys.values()))
        self.backgrounds = background(cameras, emitters)
        self._composite()

    def _composite(self) -> None:
        import mitsuba as mi

        self.targets = []
        for view, B in zip(self.views, self.backgrounds):
            a = view.mask[..., None]
            self.targets.append(mi.TensorXf((a * view.rgb + (1.0 - a) * B).astype(np.float32)))

    def set_photos(self, views) -> bool:
        """Take new photos from the same cameras (a sequence's next frame); False if the cameras differ.

        The scene and the backgrounds are kept, so only the targets are
        recomposited. With other cameras nothing changes and a new renderer is
        needed.
        """
        views = list(views)
        if [v.camera for v in views] != [v.camera for v in self.views]:
            return False
        self.views = views
        self._composite()
        return True

    def _set(self, x, c) -> None:
        self.params[self.keys["control_points"]] = x
        self.params[self.keys["control_albedo"]] = c
        self.params.update()

    def render(self, x, c, k: int, *, seed: int, spp: int | None = None):
        """Render view ``k`` with control points ``x`` and albedo ``c`` (flat ``mi.Float``, 3n each).

        Parameters
        ----------
        x, c : mi.Float (3n)
            Control points and albedo, xyz / rgb interleaved (gradients kept).
        k : int
            View.
        seed : int
            Sampler seed.
        spp : int, optional
            Samples per pixel (default: the renderer's).

        Returns
        -------
        mi.TensorXf (h, w, 3)
        """
        import mitsuba as mi

        self._set(x, c)
        return mi.render(self.scene, self.params, spp=int(spp or self.spp), seed=int(seed), sensor=int(k))

    def view_loss(self, x, c, k: int, *, seed: int, spp: int | None = None):
        """Mean L1 between the render of view ``k`` and its target; ``mi.Float (1)``, differentiable."""
        import drjit as dr

        return dr.mean(dr.abs(self.render(x, c, k, seed=seed, spp=spp) - self.targets[k]).array)

    def backward(self, x, c, view_ids, *, seed: int) -> list:
        """Accumulate the gradients of ``mean_k loss_k`` into ``x`` and ``c``; return each ``loss_k``.

        One reverse pass per view (Mitsuba releases the geometry's graph in
        each reverse render; see :meth:`mi_loop.render.multiview.Renderer.backward`).
        """
        import drjit as dr

        losses = []
        for k in view_ids:
            loss = self.view_loss(x, c, k, seed=seed * 1009 + int(k))
            losses.append(float(loss[0]))
            with one_thread(self.deterministic):
                dr.backward(loss / len(view_ids))
        return losses

    def losses(self, x, c, *, seed: int, spp: int | None = None) -> list:
        """Loss of every view (values only)."""
        import drjit as dr

        with dr.suspend_grad():
            return [float(self.view_loss(x, c, k, seed=seed + k, spp=spp)[0]) for k in range(len(self.views))]
