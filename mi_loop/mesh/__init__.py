"""Triangle meshes and point clouds in NumPy: validation, topology, geometry, sampling.

The lowest layer: nothing here imports Dr.Jit, Mitsuba or another mi_loop layer.

- :mod:`~mi_loop.mesh.checks`: shape and finiteness checks of vertex, face and point arrays;
- :mod:`~mi_loop.mesh.topology`: :func:`validate_mesh` (Loop control meshes), crease arguments;
- :mod:`~mi_loop.mesh.halfedge`: :class:`~mi_loop.mesh.halfedge.Topology`, the half-edge adjacency of a valid mesh;
- :mod:`~mi_loop.mesh.geometry`: normals, areas, edge lengths, components, welding;
- :mod:`~mi_loop.mesh.sampling`: exact closest points on triangles and area-uniform samples;
- :mod:`~mi_loop.mesh.points`: oriented point clouds, normal estimation.
"""

__all__: list[str] = []
