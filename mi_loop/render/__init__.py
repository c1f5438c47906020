"""Mitsuba 3: the variant, the ``loop_subdiv`` shape plugin, cameras and lights, multi-view losses.

- :mod:`~mi_loop.render.variant`: :func:`set_variant`, :func:`register`, the libLLVM check;
- :mod:`~mi_loop.render.plugin`: the shape ``loop_subdiv`` (the only code that knows Mitsuba's mesh buffers);
- :mod:`~mi_loop.render.scene`: cameras framing a box, lights, single renders;
- :mod:`~mi_loop.render.multiview`: a camera rig and the differentiable image loss.
"""

__all__: list = []
