"""Dr.Jit: the limit operator on the device and deterministic sparse products.

- :mod:`~mi_loop.ad.upload`: NumPy to Dr.Jit without recompiling kernels;
- :mod:`~mi_loop.ad.sparse`: gathers whose reverse pass is a gather too (no atomics, bit-reproducible);
- :mod:`~mi_loop.ad.operator`: :class:`LimitOperator`, control points to limit points, tangents, normals.

Nothing here imports Mitsuba or Dr.Jit at import time; a variant must be set
(:func:`mi_loop.set_variant`) before the functions are called.
"""

__all__: list = []
