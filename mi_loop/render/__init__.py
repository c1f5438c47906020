"""Mitsuba 3: the variant, the ``loop_subdiv`` shape plugin, cameras and lights, image losses.

- :mod:`~mi_loop.render.variant`: :func:`set_variant`, :func:`register`, the libLLVM check;
- :mod:`~mi_loop.render.plugin`: the shape ``loop_subdiv`` (the only code that knows Mitsuba's mesh buffers);
- :mod:`~mi_loop.render.cameras`: NeRF / OpenGL cameras (:class:`mi_loop.io.Camera`) as Mitsuba
  sensors (the one ``sensor_dict``), their projection, cameras framing a box (orbits, Fibonacci rigs);
- :mod:`~mi_loop.render.scene`: scenes around one shape, the rig's lights, single renders;
- :mod:`~mi_loop.render.images`: the differentiable image loss against photos or rendered
  targets (:class:`~mi_loop.render.images.ImageRenderer`);
- :mod:`~mi_loop.render.captures`: rendered targets and synthetic captures, the per-view seed;
- :mod:`~mi_loop.render.mask_trust`: which mask pixels the visual hull and the image loss
  believe (the uncertainty band, the frame's border, unseen pixels; NumPy).

The single-render helpers of :mod:`~mi_loop.render.scene` are available here too
(``from mi_loop import render; render.render_view(...)``, as in 0.1); importing
this package imports neither Mitsuba nor Dr.Jit.
"""
from mi_loop.render.scene import PLASTIC, render_limit_surface, render_view, rig_emitters, scene_dict, to_srgb

__all__ = ["PLASTIC", "render_limit_surface", "render_view", "rig_emitters", "scene_dict", "to_srgb"]
