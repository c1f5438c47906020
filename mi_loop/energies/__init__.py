"""Differentiable fitting energies in Dr.Jit.

- :mod:`~mi_loop.energies.imls`: IMLS distance of limit samples to oriented points;
- :mod:`~mi_loop.energies.coverage`: data points pull their nearest limit samples (point to plane);
- :mod:`~mi_loop.energies.arap`: as-rigid-as-possible regulariser on the control mesh;
- :mod:`~mi_loop.energies.fold`: barrier on limit normals turned over against reference normals.
"""

__all__: list = []
