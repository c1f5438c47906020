"""glTF 2.0 binary files (GLB) written: a limit mesh, or one mesh animated through morph targets.

:func:`write_glb` writes one triangle mesh with unit normals and, optionally,
linear RGB vertex colours (``COLOR_0``); :func:`write_glb_sequence` writes the
frames of a sequence in correspondence as one mesh (frame 0) with one morph
target per frame (``POSITION`` and ``NORMAL`` deltas from frame 0) and an
animation of the mesh's ``weights`` that shows frame ``k`` from ``k / fps``
(``STEP``, one-hot), which Blender, three.js and other glTF viewers play. The
material is PBR, dielectric, roughness :data:`ROUGHNESS`, double-sided.
Positions keep the caller's units and axes (glTF viewers take +Y as up).
Reading glTF is :mod:`mi_loop.io.gltf`'s and :mod:`mi_loop.io.animation`'s.

References
----------
The Khronos Group, *glTF 2.0 Specification*, sections 3.6 (meshes, morph
targets), 3.8 (materials), 3.11 (animations) and 4.4 (the GLB container).
"""
from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np

from mi_loop import __version__
from mi_loop.errors import fail
from mi_loop.io.files import atomic_open

__all__ = ["ROUGHNESS", "write_glb", "write_glb_sequence"]

#: Roughness of the material (metallic 0): a matte plastic look that shows the shape.
ROUGHNESS = 0.6
#: Base colour of a mesh without vertex colours (linear RGBA).
_GREY = [0.8, 0.8, 0.8, 1.0]
_FLOAT, _UINT = 5126, 5125                      # componentType: float32, uint32
_VERTICES, _INDICES = 34962, 34963             # bufferView.target: ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER
_JSON, _BIN = 0x4E4F534A, 0x004E4942           # chunk types
_NAME = "limit surface"


class _Chunk:
    """The BIN chunk under construction: one 4-byte aligned buffer view per accessor."""

    def __init__(self):
        self.data, self.views, self.accessors = bytearray(), [], []

    def add(self, array, kind: str, target: int | None = None, bounds: bool = False) -> int:
        """Append ``array`` (float32 or uint32, ``(n,)`` or ``(n, 3)``) as an accessor; return its index."""
        self.data += b"\0" * (-len(self.data) % 4)
        view = {"buffer": 0, "byteOffset": len(self.data), "byteLength": array.nbytes}
        if target is not None:
            view["target"] = target
        self.data += np.ascontiguousarray(array).tobytes()
        self.views.append(view)
        accessor = {"bufferView": len(self.views) - 1, "componentType": _FLOAT if array.dtype == np.float32 else _UINT,
                    "count": len(array), "type": kind}
        if bounds:                      # the stored float32 values' bounds, as the specification requires
            accessor["min"] = np.atleast_1d(array.min(axis=0)).tolist()
            accessor["max"] = np.atleast_1d(array.max(axis=0)).tolist()
        self.accessors.append(accessor)
        return len(self.accessors) - 1


def _checked(func: str, V, F, normals, colors, sequence: bool):
    """``(V (T, n, 3) float64, F uint32, unit normals (T, n, 3) float64, colours float32 or None)``, checked."""
    V, normals, F = np.asarray(V, dtype=np.float64), np.asarray(normals, dtype=np.float64), np.asarray(F)
    shape = "(T, n, 3), T > 0, n > 0" if sequence else "(n, 3), n > 0"
    if not sequence:
        V, normals = V[None], normals[None]
    if V.ndim != 3 or V.shape[2] != 3 or 0 in V.shape:
        fail(func, f"V of shape {shape}", f"shape {V.shape if sequence else V.shape[1:]}")
    where = (lambda t: f" in frame {t}") if sequence else (lambda t: "")
    if not np.isfinite(V).all():
        t, i = np.argwhere(~np.isfinite(V).all(axis=2))[0]
        fail(func, "finite vertex positions", f"vertex {i} = {V[t, i].tolist()}{where(t)}")
    if F.ndim != 2 or F.shape[1] != 3 or len(F) == 0 or not np.issubdtype(F.dtype, np.integer):
        fail(func, "integer faces F of shape (m, 3), m > 0", f"{F.dtype} array of shape {F.shape}")
    if F.min() < 0 or F.max() >= V.shape[1]:
        bad = int(np.flatnonzero((F < 0).any(1) | (F >= V.shape[1]).any(1))[0])
        fail(func, f"face indices in [0, {V.shape[1]})", f"face {bad} = {F[bad].tolist()}")
    if normals.shape != V.shape:
        fail(func, f"normals of V's shape {V.shape if sequence else V.shape[1:]}",
             f"shape {normals.shape if sequence else normals.shape[1:]}")
    length = np.linalg.norm(normals, axis=-1)
    if not (np.isfinite(length) & (length > 0)).all():
        t, i = np.argwhere(~(np.isfinite(length) & (length > 0)))[0]
        fail(func, "finite, non-zero normals", f"normal {i} = {normals[t, i].tolist()}{where(t)}")
    if colors is not None:
        colors = np.asarray(colors, dtype=np.float32)
        if colors.shape != V.shape[1:]:
            fail(func, f"colors of shape {V.shape[1:]}", f"shape {colors.shape}")
        bad = ~((colors >= 0) & (colors <= 1)).all(axis=1)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            fail(func, "linear RGB colors in [0, 1]", f"color {i} = {colors[i].tolist()}")
    return V, F.astype(np.uint32), normals / length[..., None], colors


def _document(V, F, N, colors):
    """The glTF JSON and BIN chunk of one mesh in one node of one scene."""
    chunk = _Chunk()
    attributes = {"POSITION": chunk.add(V.astype(np.float32), "VEC3", _VERTICES, bounds=True),
                  "NORMAL": chunk.add(N.astype(np.float32), "VEC3", _VERTICES)}
    if colors is not None:
        attributes["COLOR_0"] = chunk.add(colors, "VEC3", _VERTICES)
    primitive = {"attributes": attributes, "indices": chunk.add(F.ravel(), "SCALAR", _INDICES),
                 "material": 0, "mode": 4}
    doc = {"asset": {"version": "2.0", "generator": f"mi_loop {__version__}"},
           "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0, "name": _NAME}],
           "meshes": [{"name": _NAME, "primitives": [primitive]}],
           "materials": [{"name": _NAME, "doubleSided": True,
                          "pbrMetallicRoughness": {"baseColorFactor": _GREY if colors is None else [1.0] * 4,
                                                   "metallicFactor": 0.0, "roughnessFactor": ROUGHNESS}}]}
    return doc, chunk


def _write(path, doc: dict, chunk: _Chunk) -> Path:
    """The GLB container: 12-byte header, JSON chunk (space-padded), BIN chunk (zero-padded), atomically."""
    doc["buffers"] = [{"byteLength": len(chunk.data)}]
    doc["bufferViews"], doc["accessors"] = chunk.views, chunk.accessors
    text = json.dumps(doc, separators=(",", ":")).encode("utf-8")
    text += b" " * (-len(text) % 4)
    data = bytes(chunk.data) + b"\0" * (-len(chunk.data) % 4)
    total = 12 + 8 + len(text) + 8 + len(data)
    path = Path(path)
    with atomic_open(path) as f:
        f.write(struct.pack("<4sII", b"glTF", 2, total))
        f.write(struct.pack("<II", len(text), _JSON) + text)
        f.write(struct.pack("<II", len(data), _BIN) + data)
    return path


def write_glb(path, V, F, normals, colors=None) -> Path:
    """Write a triangle mesh with unit normals (and vertex colours) as a GLB file, atomically.

    Parameters
    ----------
    path : str or os.PathLike
        Destination (``.glb``); its directory must exist.
    V : (n, 3) float array-like
        Vertex positions, stored as float32 with their exact bounds.
    F : (m, 3) int array-like
        Triangles, indices in ``[0, n)``, stored as uint32.
    normals : (n, 3) float array-like
        Per-vertex normals (e.g. exact limit normals), normalised and stored as float32.
    colors : (n, 3) float array-like, optional
        Linear RGB in [0, 1] per vertex (an albedo), stored as float32
        ``COLOR_0``, which glTF defines as linear (the material's base colour
        factor is then white; without colours it is grey 0.8).

    Returns
    -------
    pathlib.Path
        The written path.

    Raises
    ------
    ValueError
        Wrong shapes, non-finite positions, face indices out of range, a zero
        normal, colours outside [0, 1]; the message names the offending element.

    Examples
    --------
    >>> import tempfile, os
    >>> from mi_loop.io.gltf import GltfFile
    >>> with tempfile.TemporaryDirectory() as d:
    ...     p = write_glb(os.path.join(d, "t.glb"), np.eye(3), [[0, 1, 2]], np.ones((3, 3)))
    ...     g = GltfFile(p, "example")
    ...     g.accessor(g.doc["meshes"][0]["primitives"][0]["attributes"]["POSITION"]).tolist()
    [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    """
    V, F, N, colors = _checked("write_glb", V, F, normals, colors, sequence=False)
    doc, chunk = _document(V[0], F, N[0], colors)
    return _write(path, doc, chunk)


def write_glb_sequence(path, V, F, normals, fps: float = 24.0, names=None, colors=None) -> Path:
    """Write frames in correspondence as one mesh animated by morph targets, a GLB file, atomically.

    Parameters
    ----------
    path : str or os.PathLike
        Destination (``.glb``); its directory must exist.
    V : (T, n, 3) float array-like
        Vertex positions of every frame; frame 0 is the mesh, frame ``k`` its
        morph target ``k`` (``V[k] - V[0]`` in float32, with its bounds).
    F : (m, 3) int array-like
        Triangles, the same in every frame.
    normals : (T, n, 3) float array-like
        Normals of every frame, normalised; the targets hold their differences from frame 0.
    fps : float, optional
        Frame rate: frame ``k`` is shown from ``t = k / fps`` (animation
        ``'sequence'``, ``STEP`` interpolation of one-hot ``weights``).
    names : list of str, optional
        One name per frame, stored as the mesh's ``extras.targetNames`` (the
        shape-key names in Blender); default ``'frame 0'``, ``'frame 1'``, ...
    colors : (n, 3) float array-like, optional
        Linear RGB in [0, 1] per vertex, the same in every frame (``COLOR_0``).

    Returns
    -------
    pathlib.Path
        The written path.

    Raises
    ------
    ValueError
        As :func:`write_glb`; ``fps`` not finite and positive, ``names`` not
        one per frame.
    TypeError
        ``fps`` not a number.

    Notes
    -----
    Where the animation does not play, the mesh's default ``weights``
    (one-hot on target 0, whose deltas are zero) show frame 0. A player
    evaluates :math:`V_0 + \\sum_k w_k(t) (V_k - V_0)` with :math:`w(t)` the
    unit vector of frame :math:`\\lfloor t \\cdot fps \\rfloor`.
    """
    func = "write_glb_sequence"
    V, F, N, colors = _checked(func, V, F, normals, colors, sequence=True)
    T = len(V)
    if isinstance(fps, bool) or not isinstance(fps, (int, float, np.integer, np.floating)):
        fail(func, "fps as a number", f"{type(fps).__name__} {fps!r}", TypeError)
    if not (np.isfinite(fps) and fps > 0):
        fail(func, "fps, a finite number > 0", float(fps))
    names = [f"frame {k}" for k in range(T)] if names is None else [str(n) for n in names]
    if len(names) != T:
        fail(func, f"one name per frame ({T} frames)", f"{len(names)} names")
    doc, chunk = _document(V[0], F, N[0], colors)
    mesh = doc["meshes"][0]
    mesh["primitives"][0]["targets"] = [
        {"POSITION": chunk.add((V[k] - V[0]).astype(np.float32), "VEC3", _VERTICES, bounds=True),
         "NORMAL": chunk.add((N[k] - N[0]).astype(np.float32), "VEC3", _VERTICES)} for k in range(T)]
    mesh["weights"] = np.eye(T)[0].tolist()
    mesh["extras"] = {"targetNames": names}
    times = chunk.add((np.arange(T) / float(fps)).astype(np.float32), "SCALAR", bounds=True)
    weights = chunk.add(np.eye(T, dtype=np.float32).ravel(), "SCALAR")
    doc["animations"] = [{"name": "sequence", "samplers": [{"input": times, "output": weights,
                                                            "interpolation": "STEP"}],
                          "channels": [{"sampler": 0, "target": {"node": 0, "path": "weights"}}]}]
    return _write(path, doc, chunk)
