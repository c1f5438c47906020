"""Files: mesh and point-cloud readers, atomic writers of meshes, images and text.

The only package that opens files (the Mitsuba plugin reads its control mesh
through it); it sits just above :mod:`mi_loop.mesh`.

- :mod:`~mi_loop.io.meshes`: :func:`read_mesh`, :func:`read_control_mesh` (with the
  count of polygons split into triangles), :func:`write_ply`, :func:`write_obj`;
- :mod:`~mi_loop.io.glb`: :func:`write_glb` (a limit mesh with normals and colours) and
  :func:`write_glb_sequence` (frames in correspondence as morph targets, animated);
- :mod:`~mi_loop.io.frames`: :func:`read_frames` (sequences of meshes or point clouds, each frame
  read as a :class:`FrameData`);
- :mod:`~mi_loop.io.runs`: the files a ``fit-sequence`` run reads back, one writer and one reader
  each: ``metrics.csv`` (:class:`MetricsRow`), ``sequence.json`` (:class:`RunRecord`),
  ``state/NNNN.npz`` (:class:`FrameState`), and a fit's ``report.json`` (:func:`read_report`);
- :mod:`~mi_loop.io.documents`: JSON files (:func:`read_json`) and the package's own text files
  (:func:`read_package_text`, the report viewer's scripts);
- :mod:`~mi_loop.io.animation`: :func:`bake_animation` (a skinned or node-animated glTF clip as
  meshes in correspondence, :class:`BakedAnimation`), :func:`animation_names`; it reads files
  through :mod:`~mi_loop.io.gltf` (GLB / glTF container, accessors, base colours);
- :mod:`~mi_loop.io.points`: :func:`load_oriented_points` (point clouds, or meshes sampled);
- :mod:`~mi_loop.io.capture`: calibrated multi-view captures, NeRF / Blender ``transforms.json``
  (:func:`read_capture`, :func:`write_capture` from :mod:`~mi_loop.io.capture_writer`), with the
  data classes of :mod:`~mi_loop.io.views` (:class:`Camera`, :class:`View`, :class:`Capture`);
  photos decoded by :mod:`~mi_loop.io.pixels` (JPEGs reduced at decode time) and resampled to
  ideal pinholes by :mod:`~mi_loop.io.undistort` (OpenCV's lens models, area averaging);
- :mod:`~mi_loop.io.formats`, :mod:`~mi_loop.io.ply`: the file formats, as polygon lists;
- :mod:`~mi_loop.io.srgb`: the sRGB curve (:func:`srgb_to_linear`, :func:`linear_to_srgb`);
- :mod:`~mi_loop.io.files`: atomic writes (:func:`write_png`, :func:`write_text`),
  :func:`staged_outputs`, output directories.

Every rejected file raises :class:`ValueError` reading ``function(): expected
..., got ...`` with the file's path and the offending vertex, face or line.
"""
from __future__ import annotations

from mi_loop.io.animation import BakedAnimation, animation_names, bake_animation
from mi_loop.io.capture import (
    IMAGE_SUFFIXES,
    Camera,
    Capture,
    View,
    read_capture,
    write_capture,
)
from mi_loop.io.documents import read_json, read_package_text
from mi_loop.io.files import (
    atomic_open,
    ensure_writable_dir,
    first_missing_ancestor,
    remove_if_empty,
    staged_outputs,
    write_png,
    write_text,
)
from mi_loop.io.frames import FRAME_SUFFIXES, FrameData, read_frames
from mi_loop.io.glb import write_glb, write_glb_sequence
from mi_loop.io.meshes import (
    MESH_SUFFIXES,
    ControlMesh,
    read_control_mesh,
    read_creases,
    read_mesh,
    read_vertex_colors,
    write_obj,
    write_ply,
)
from mi_loop.io.points import POINT_SUFFIXES, load_oriented_points
from mi_loop.io.runs import (
    FrameState,
    MetricsRow,
    RunRecord,
    read_metrics,
    read_report,
    read_run_json,
    read_state,
    write_metrics,
    write_run_json,
    write_state,
)
from mi_loop.io.srgb import linear_to_srgb, srgb_to_linear

__all__ = [
    "FRAME_SUFFIXES",
    "IMAGE_SUFFIXES",
    "MESH_SUFFIXES",
    "POINT_SUFFIXES",
    "BakedAnimation",
    "Camera",
    "Capture",
    "ControlMesh",
    "FrameData",
    "FrameState",
    "MetricsRow",
    "RunRecord",
    "View",
    "animation_names",
    "atomic_open",
    "bake_animation",
    "ensure_writable_dir",
    "first_missing_ancestor",
    "linear_to_srgb",
    "load_oriented_points",
    "read_capture",
    "read_control_mesh",
    "read_frames",
    "read_json",
    "read_mesh",
    "read_creases",
    "read_metrics",
    "read_package_text",
    "read_report",
    "read_run_json",
    "read_state",
    "read_vertex_colors",
    "remove_if_empty",
    "srgb_to_linear",
    "staged_outputs",
    "write_capture",
    "write_glb",
    "write_glb_sequence",
    "write_metrics",
    "write_obj",
    "write_ply",
    "write_png",
    "write_run_json",
    "write_state",
    "write_text",
]
