"""Loop subdivision and its exact limit surface, as sparse linear operators (NumPy/SciPy).

- :mod:`~mi_loop.subdiv.subdivision`: one Loop step as a sparse matrix, boundary and crease rules;
- :mod:`~mi_loop.subdiv.hierarchy`: the control mesh refined until every face has one irregular corner at most;
- :mod:`~mi_loop.subdiv.boxspline`, :mod:`~mi_loop.subdiv.patches`, :mod:`~mi_loop.subdiv.irregular`,
  :mod:`~mi_loop.subdiv.limit`: exact evaluation at any ``(face, u, v)``, :func:`limit_matrix`;
- :mod:`~mi_loop.subdiv.masks`: the limit at the control vertices (masks) and dense limit meshes;
- :mod:`~mi_loop.subdiv.tessellation`: uniform ``(face, u, v)`` samples and their triangles, one corner
  sample per control vertex.

Within the sub-package imports point one way: ``masks`` uses ``limit``, never the reverse.
"""

__all__: list[str] = []
