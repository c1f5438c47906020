"""Files: mesh and point-cloud readers, atomic writers of meshes, images and text.

The only package that opens files (the Mitsuba plugin reads its control mesh
through it); it sits just above :mod:`mi_loop.mesh`.

- :mod:`~mi_loop.io.meshes`: :func:`read_mesh`, :func:`write_ply`, :func:`read_frames`;
- :mod:`~mi_loop.io.points`: :func:`load_oriented_points` (point clouds, or meshes sampled);
- :mod:`~mi_loop.io.files`: atomic writes (:func:`write_png`, :func:`write_text`),
  :func:`staged_outputs`, output directories.
"""
from __future__ import annotations

from mi_loop.io.files import (atomic_open, ensure_writable_dir, first_missing_ancestor, remove_if_empty,
                              staged_outputs, write_png, write_text)
from mi_loop.io.meshes import MESH_SUFFIXES, read_frames, read_mesh, write_ply
from mi_loop.io.points import load_oriented_points

__all__ = ["MESH_SUFFIXES", "atomic_open", "ensure_writable_dir", "first_missing_ancestor",
           "load_oriented_points", "read_frames", "read_mesh", "remove_if_empty", "staged_outputs",
           "write_png", "write_ply", "write_text"]
