"""Mitsuba 3: the variant, the ``loop_subdiv`` shape plugin, cameras and lights, multi-view losses.

- :mod:`~mi_loop.render.variant`: :func:`set_variant`, :func:`register`, the libLLVM check;
- :mod:`~mi_loop.render.plugin`: the shape ``loop_subdiv`` (the only code that knows Mitsuba's mesh buffers);
- :mod:`~mi_loop.render.scene`: cameras framing a box, lights, single renders;
- :mod:`~mi_loop.render.cameras`: NeRF / OpenGL cameras (:class:`mi_loop.io.Camera`) as Mitsuba
  sensors, their projection, Fibonacci rigs (import it: its ``sensor_dict`` is not the one here);
- :mod:`~mi_loop.render.multiview`: a camera rig and the differentiable image loss.

The single-render helpers of :mod:`~mi_loop.render.scene` are available here too
(``from mi_loop import render; render.render_view(...)``, as in 0.1); importing
this package imports neither Mitsuba nor Dr.Jit.
"""
from mi_loop.render.scene import (
                                  PLASTIC,
                                  look_at_bbox,
                                  render_limit_surface,
                                  render_view,
                                  scene_dict,
                                  sensor_dict,
                                  to_srgb,
)

__all__ = ["PLASTIC", "look_at_bbox", "render_limit_surface", "render_view", "scene_dict", "sensor_dict",
           "to_srgb"]
