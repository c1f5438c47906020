"""The jobs' inputs as fitting data: oriented points, templates checked against the data, frames.

- :func:`load_input`: ``mi-loop fit``'s INPUT as oriented points (normals
  estimated and oriented when the file has none) and a target for the pictures;
- :func:`read_template`: a ``--template`` control mesh, validated, with the
  number of polygons the reader split into triangles, and checked to lie in the
  data's frame (:func:`check_template_frame`);
- :class:`FrameReader`: the frames of a sequence, one at a time, the same way, each a :class:`FitFrame`.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mi_loop import io
from mi_loop.errors import expected

__all__ = ["MAX_CENTRE_OFFSET", "MAX_SIZE_RATIO", "NO_CROSSING_NOTE", "FitFrame", "FrameReader", "check_template_frame",
           "load_input", "read_template", "say_handles"]

#: What the terms line of ``fit`` and ``fit-sequence`` adds with ``--no-crossing``.
NO_CROSSING_NOTE = "; no step crosses the surface (--no-crossing)"

#: A template's bounding-box diagonal must be within this factor of the data's.
MAX_SIZE_RATIO = 2.0
#: ... and its bounding-box centre within this fraction of the data's diagonal from the data's centre.
MAX_CENTRE_OFFSET = 0.25


def load_input(path: Path, log):
    """Read ``mi-loop fit``'s INPUT as oriented points, and a target for the pictures.

    Parameters
    ----------
    path : pathlib.Path
        A point cloud or mesh file (see :func:`~mi_loop.io.points.load_oriented_points`).
    log : Reporter
        Where the note about estimated normals goes.

    Returns
    -------
    P, N : (k, 3) float64 NumPy arrays
        Points and unit normals (estimated and oriented when the file has none).
    target : tuple
        ``('mesh', V, F)`` for a mesh file, else ``('points', P, N)``.
    info : dict
        :func:`~mi_loop.io.points.load_oriented_points`'s, plus
        ``normals_estimated`` when the file had no normals.

    Raises
    ------
    ValueError
        If the file is missing, unreadable or holds no usable points (one-line message).
    """
    from mi_loop.io.points import load_oriented_points
    from mi_loop.mesh.points import estimate_normals

    P, N, info = load_oriented_points(path)
    if N is None:
        log.say(f"{path.name}: {len(P)} points without normals: estimating and orienting normals")
        N = estimate_normals(P)
        info["normals_estimated"] = True
    target = ("points", P, N)
    if info.get("kind") == "mesh":
        V, F = io.read_mesh(path)
        target = ("mesh", V, F)
    return P, N, target, info


def _box(X):
    lo, hi = X.min(0), X.max(0)
    return lo, hi, (lo + hi) / 2, float(np.linalg.norm(hi - lo))


def check_template_frame(V, P, where: str) -> dict:
    """Check that a template lies in the data's frame: similar size, overlapping position.

    Parameters
    ----------
    V : (n, 3) float numpy array
        Template control points.
    P : (k, 3) float numpy array
        Data points (same units as ``V`` should be).
    where : str
        Who checks, for the message (``"fit --template 'cage.ply'"``).

    Returns
    -------
    dict
        ``size_ratio`` (template diagonal / data diagonal) and ``centre_offset``
        (distance of the box centres / data diagonal).

    Raises
    ------
    ValueError
        If the size ratio is outside ``[1/MAX_SIZE_RATIO, MAX_SIZE_RATIO]`` or the
        offset above :data:`MAX_CENTRE_OFFSET`; the message gives both boxes
        and says to scale and translate the template onto the data.
    """
    lo_d, hi_d, c_d, diag_d = _box(np.asarray(P, dtype=np.float64))
    lo_t, hi_t, c_t, diag_t = _box(np.asarray(V, dtype=np.float64))
    ratio = diag_t / diag_d if diag_d > 0 else np.inf
    offset = float(np.linalg.norm(c_t - c_d)) / diag_d if diag_d > 0 else np.inf
    if 1 / MAX_SIZE_RATIO <= ratio <= MAX_SIZE_RATIO and offset <= MAX_CENTRE_OFFSET:
        return {"size_ratio": ratio, "centre_offset": offset}

    def box(lo, hi):
        return f"[{', '.join(f'{v:.3g}' for v in lo)}] to [{', '.join(f'{v:.3g}' for v in hi)}]"

    raise ValueError(expected(
        where, f"a control mesh in the data's frame (bounding-box diagonal within a factor {MAX_SIZE_RATIO:g} "
        f"of the data's, centre within {MAX_CENTRE_OFFSET:g} of its diagonal)",
        f"a template {ratio:.3g}x the data's size whose centre is {offset:.3g} data diagonals away "
        f"(template box {box(lo_t, hi_t)}, data box {box(lo_d, hi_d)}); scale and translate the "
        "template onto the data"))


def read_template(path: Path, P, where: str, log):
    """Read and validate a ``--template`` control mesh and check it against the data points ``P``.

    A file with polygons of more than three corners (a quad cage) is split into
    triangle fans on reading; a one-line warning names how many.

    Parameters
    ----------
    path : pathlib.Path
        Control mesh file (PLY, OBJ, OFF, glTF/GLB).
    P : (k, 3) float NumPy array
        The data points, in the units the template must share (:func:`check_template_frame`).
    where : str
        Who reads it, for messages (``"fit --template 'cage.ply'"``).
    log : Reporter
        Where the warning about split polygons goes.

    Returns
    -------
    V : (n, 3) float64 numpy array
    F : (m, 3) int64 numpy array
    info : dict
        ``source``, ``path``, ``n_vertices``, ``n_faces``, ``split_polygons``
        (the file's faces that were split into triangles), ``size_ratio``,
        ``centre_offset``.

    Raises
    ------
    ValueError
        If the file cannot be read, the mesh is invalid (:func:`~mi_loop.mesh.topology.validate_mesh`)
        or it is not in the data's frame.
    """
    from mi_loop.mesh.topology import validate_mesh

    mesh = io.read_control_mesh(path)
    V, F, _ = validate_mesh(mesh.V, mesh.F, where)
    split = int(mesh.n_split)
    if split:
        log.warning(f"{where}: {split} faces with more than three corners were split into triangles "
                 f"({len(F)} triangles); the Loop surface of the triangulated mesh is fitted")
    info = {"source": "file", "path": str(path), "n_vertices": len(V), "n_faces": len(F),
            "split_polygons": split}
    info.update(check_template_frame(V, P, where))
    return V, F, info


@dataclass(frozen=True, eq=False)
class FitFrame:
    """One frame of a sequence as fitting data: oriented points, and the mesh where the frame is one.

    Attributes
    ----------
    name : str
        The frame's name (:attr:`mi_loop.io.frames.FrameData.name`).
    P : (k, 3) float NumPy array
        Points: sampled on a mesh frame, or the point cloud's own.
    N : (k, 3) float NumPy array
        Their unit normals (a point cloud's estimated ones when its file has none).
    mesh : tuple ``(V (n, 3) float, F (m, 3) int)`` or None
        The frame's mesh; None for a point cloud.
    """

    name: str
    P: np.ndarray
    N: np.ndarray
    mesh: tuple | None = None


class FrameReader:
    """The frames of a sequence as fitting data, read one at a time.

    Parameters
    ----------
    frames : list of mi_loop.io.frames.Frame
        :func:`mi_loop.io.read_frames` output.
    n_points : int
        Points sampled on every mesh frame.
    seed : int
        Frame ``t`` is sampled with ``seed + t``.
    log : mi_loop.app.progress.Reporter
        Told once that normals are estimated (point clouds without normals).
    """

    def __init__(self, frames, n_points: int, seed: int, log):
        self.frames, self.n_points, self.seed, self.log = frames, n_points, seed, log
        self.normals_estimated = False

    def __len__(self) -> int:
        return len(self.frames)

    def _read(self, t: int):
        """Frame ``t`` as read (:class:`~mi_loop.io.frames.FrameData`), checked, with normals where it needs them."""
        from dataclasses import replace

        from mi_loop.mesh.points import estimate_normals

        frame = self.frames[t]()
        X = frame.vertices
        if not np.isfinite(X).all():
            bad = int(np.flatnonzero(~np.isfinite(X).all(1))[0])
            raise ValueError(expected("fit-sequence FRAMES", f"finite coordinates in frame {frame.name}",
                                      f"vertex {bad} = {X[bad].tolist()}"))
        if frame.faces is None and frame.normals is None:
            if not self.normals_estimated:
                self.log.say("point-cloud frames without normals: estimating and orienting normals "
                             "in every frame")
            self.normals_estimated = True
            frame = replace(frame, normals=estimate_normals(X))
        return frame

    def __call__(self, t: int) -> FitFrame:
        """Frame ``t`` as a :class:`FitFrame` (a mesh frame sampled with ``seed + t``)."""
        from mi_loop.mesh.sampling import sample_surface

        frame = self._read(t)
        if frame.faces is None:
            return FitFrame(frame.name, frame.vertices, frame.normals)
        P, Np, _ = sample_surface(frame.vertices, frame.faces, self.n_points, seed=self.seed + t)
        return FitFrame(frame.name, P, Np, (frame.vertices, frame.faces))

    def target(self, t: int):
        """Frame ``t`` for the pictures: ``('mesh', V, F)`` or ``('points', P, N)``."""
        frame = self._read(t)
        if frame.faces is not None:
            return ("mesh", frame.vertices, frame.faces)
        return ("points", frame.vertices, frame.normals)


def say_handles(info: dict, genus, log) -> None:
    """Log how many handles a template builder cut (its ``info["handles_cut"]``), if it cut any.

    Parameters
    ----------
    info : dict
        The builder's info (:func:`~mi_loop.fitting.template.make_template`, ``mesh_template``); a
        template without ``handles_cut`` (a user's, a feature template) says nothing.
    genus : int or None
        The genus they were cut to.
    log : mi_loop.app.progress.Reporter
        Where the line goes.
    """
    loops = info.get("handles_cut")
    if loops:
        log.say(f"template: {len(loops)} handle{'s' if len(loops) > 1 else ''} cut to genus {genus} (loops "
                f"{min(loops):.3g}-{max(loops):.3g} long in the unit box)")
