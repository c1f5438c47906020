"""A rig of cameras around a subject and the differentiable image loss of a ``loop_subdiv`` shape.

:class:`Renderer` renders the limit surface from a subset of the rig's views
with ``direct_projective`` (gradients through silhouettes and shading) and
compares each view with a target image: mean L1 or L2 over the pixels.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mi_loop.ad.control import ControlPoints
from mi_loop.ad.threads import one_thread
from mi_loop.render.plugin import create, plain_mesh
from mi_loop.render.scene import scene_dict

__all__ = ["IMAGE_MODES", "LOSSES", "Renderer", "RigOptions", "rig_views"]

IMAGE_MODES = ("shading", "silhouette")
LOSSES = ("l1", "l2")


@dataclass(frozen=True)
class RigOptions:
    """What :class:`Renderer` renders: the rig, the images and the loss.

    Attributes
    ----------
    views : int
        Cameras on a Fibonacci sphere around the subject.
    resolution : int
        Image width and height in pixels.
    spp : int
        Samples per pixel of the differentiable renders.
    target_spp : int
        Samples per pixel of the target renders.
    level : int
        Tessellation level of the rendered limit surface.
    loss : {'l1', 'l2'}
        Pixel loss.
    mode : {'shading', 'silhouette'}
        Grey diffuse shading under a key light and an environment, or a black
        silhouette against a white environment.
    deterministic : bool
        Run the reverse render on one LLVM thread (:func:`mi_loop.ad.threads.one_thread`):
        Mitsuba scatters the image gradient into the vertex buffer with atomic
        adds, whose order otherwise changes from run to run. Slower.
    """

    views: int = 20
    resolution: int = 96
    spp: int = 4
    target_spp: int = 32
    level: int = 1
    loss: str = "l1"
    mode: str = "shading"
    deterministic: bool = False


def rig_views(n_views: int):
    """``n_views`` (azimuth, elevation) pairs in degrees spread over the whole sphere.

    Fibonacci-sphere directions (y up), so every part of the subject is seen.

    Parameters
    ----------
    n_views : int
        Number of cameras, at least 1.

    Returns
    -------
    list of (float, float)
        Azimuth in ``[0, 360)`` and elevation in ``(-90, 90)`` degrees.

    Examples
    --------
    >>> [round(e) for _, e in rig_views(3)]
    [42, 0, -42]
    """
    if n_views < 1:
        raise ValueError(f"rig_views(): expected at least one view, got {n_views}")
    i = np.arange(n_views) + 0.5
    y = 1.0 - 2.0 * i / n_views
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    elevation = np.degrees(np.arcsin(np.clip(y, -1, 1)))
    azimuth = np.degrees(phi) % 360.0
    return [(float(a), float(e)) for a, e in zip(azimuth, elevation)]


class Renderer:
    """Prediction scene (``loop_subdiv``, ``direct_projective``) and target renders.

    Parameters
    ----------
    V0, F : numpy arrays
        Control mesh (normalised units) whose limit surface is rendered.
    bbox : ((3,), (3,))
        Box framing the subject for the whole sequence (fixed cameras).
    options : RigOptions
    """

    def __init__(self, V0, F, bbox, options: RigOptions):
        import mitsuba as mi

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
        desc = scene_dict(shape, views=self.views, resolution=self.options.resolution,
                          integrator=integrator, sample_border=True, bbox=self.bbox)
        if self.options.mode == "silhouette":
            desc.pop("key_light", None)
        return desc

    def targets(self, V, F, normals=None):
        """Render a target frame (a triangle mesh) from every view; list of ``mi.TensorXf``."""
        import drjit as dr
        import mitsuba as mi

        mesh = plain_mesh(V, F, normals=normals, bsdf=mi.load_dict(self._bsdf))
        scene = mi.load_dict(self._scene_dict(mesh, {"type": "direct"}))
        images = []
        for k in range(len(self.views)):
            img = mi.render(scene, spp=self.options.target_spp, seed=10_000 + k, sensor=k)
            dr.eval(img)
            images.append(img)
        return images

    def view_loss(self, x, k: int, targets, seed: int):
        """Image loss of control points ``x`` in view ``k`` (differentiable, ``mi.Float (1)``).

        Parameters
        ----------
        x : ControlPoints or mi.Float (3n)
            Control points (normalised units), possibly with gradients.
        k : int
            View.
        targets : list of mi.TensorXf
            Target images of every view (:meth:`targets`).
        seed : int
            Seed of the render's sampler.

        Returns
        -------
        mi.Float (1)
        """
        import drjit as dr
        import mitsuba as mi

        self.params[self.key] = x.flat if isinstance(x, ControlPoints) else x
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
        vertex positions (checked in ``tests/render/test_multiview.py``).
        """
        import drjit as dr

        total = 0.0
        for k in view_ids:
            L = self.view_loss(x, k, targets, seed)
            total += float(L[0])
            with one_thread(self.options.deterministic):
                dr.backward(L * (weight / len(view_ids)))
        return total / len(view_ids)

    def loss(self, x, view_ids, targets, seed: int):
        """Mean image loss over ``view_ids`` (value only; see :meth:`backward` for gradients)."""
        import drjit as dr

        with dr.suspend_grad():
            return sum(float(self.view_loss(x, k, targets, seed)[0]) for k in view_ids) / len(view_ids)
