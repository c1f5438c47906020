"""Read the fitting input: oriented point clouds, or meshes sampled into oriented points.

Formats: PLY (vertex-only point clouds with or without ``nx ny nz``, or
meshes), XYZ/PTS/TXT text (3 columns ``x y z`` or 6 columns ``x y z nx ny
nz``), NPZ (``points`` and optional ``normals``), OBJ, OFF and glTF/GLB meshes
(a glTF scene's meshes are all sampled, each placed by its node; an OBJ or
OFF file without faces is a point cloud). Point clouds without normals get
them from :func:`mi_loop.mesh.points.estimate_normals` (PCA + MST orientation).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from mi_loop.errors import fail
from mi_loop.io.formats import fan_triangulate, ply_polygons, read_polygons
from mi_loop.io.ply import read_ply

__all__ = ["DEFAULT_SAMPLES", "POINT_SUFFIXES", "load_oriented_points"]

#: Suffixes that :func:`load_oriented_points` reads.
POINT_SUFFIXES = (".ply", ".xyz", ".pts", ".txt", ".npz", ".obj", ".off", ".glb", ".gltf")
#: Surface samples drawn from a mesh when ``n_samples`` is None (at least this many).
DEFAULT_SAMPLES = 100_000
_FUNC = "load_oriented_points"


def load_oriented_points(path, n_samples: int | None = None, seed: int = 0):
    """Read points and normals from a point-cloud or mesh file.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.ply``, ``.xyz``, ``.pts``, ``.txt``, ``.npz``, ``.obj``, ``.off``,
        ``.glb`` or ``.gltf`` file. An NPZ holds ``points`` (any float type) and
        optional ``normals``; with ``loc`` and ``scale`` (Occupancy Networks and
        Occupancy Flow, which publish D-FAUST so: ``points = (X - loc) / scale``)
        the points are returned in their own frame, ``points * scale + loc``.
    n_samples : int or None
        Meshes: number of surface samples (default ``max(100_000, #vertices)``).
        Point clouds: if given and smaller than the point count, a random subset
        of that size (without replacement); otherwise all points are kept.
    seed : int
        Seed of the surface sampling / subset.

    Returns
    -------
    P : (N, 3) float64 NumPy array
        Points.
    N : (N, 3) float64 NumPy array or None
        Unit normals, or None when the file holds none (point clouds only; see
        :func:`mi_loop.mesh.points.estimate_normals`). Mesh samples carry the face normals.
    info : dict
        ``format`` (suffix), ``kind`` (``"points"`` or ``"mesh"``),
        ``n_file`` (points or vertices in the file), ``n_faces`` (meshes, after
        triangulation), ``n_points`` (returned), ``has_normals``, ``subsampled``, ``seed``.

    Raises
    ------
    ValueError
        Missing or unreadable file, unknown suffix, no points, NaN/Inf points,
        zero-length normals (names the first index), point/normal count
        mismatch, wrong column count, bad ``n_samples``; every message reads
        ``load_oriented_points(): expected ..., got ...`` and names the file.

    Examples
    --------
    >>> import tempfile, os
    >>> with tempfile.TemporaryDirectory() as d:
    ...     p = os.path.join(d, "cloud.xyz")
    ...     _ = open(p, "w").write("0 0 0 0 0 2\\n1 0 0 0 0 1\\n")
    ...     P, N, info = load_oriented_points(p)
    >>> N.tolist(), info["kind"], info["has_normals"]
    ([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]], 'points', True)
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in POINT_SUFFIXES:
        fail(_FUNC, f"a {', '.join(POINT_SUFFIXES)} file", f"'{path}' (suffix '{path.suffix}')")
    if not path.is_file():
        fail(_FUNC, "an existing file", f"'{path}': no such file")
    if n_samples is not None and (isinstance(n_samples, bool) or not isinstance(n_samples, (int, np.integer))
                                  or n_samples < 1):
        fail(_FUNC, "n_samples a positive integer or None", repr(n_samples))
    mesh = None
    if suffix in (".xyz", ".pts", ".txt"):
        P, N = _read_text(path)
    elif suffix == ".npz":
        P, N = _read_npz(path)
    elif suffix == ".ply":
        P, N, mesh = _read_ply(path)
    else:
        V, counts, items = read_polygons(path, _FUNC, objects="all")
        P, N, mesh = (V, None, None) if len(counts) == 0 else (None, None, (V, fan_triangulate(counts, items)[0]))
    info = {"format": suffix[1:], "seed": int(seed), "subsampled": False}
    if mesh is not None:
        P, N = _sample_mesh(*mesh, n_samples, seed, path)
        info.update(kind="mesh", n_file=len(mesh[0]), n_faces=len(mesh[1]))
    else:
        info.update(kind="points", n_file=len(P))
    P, N = _check_points(P, N, path)
    if mesh is None and n_samples is not None and n_samples < len(P):
        keep = np.sort(np.random.default_rng(seed).choice(len(P), n_samples, replace=False))
        P, N = P[keep], (None if N is None else N[keep])
        info["subsampled"] = True
    info.update(n_points=len(P), has_normals=N is not None)
    return P, N, info


def _check_points(P, N, path):
    """Check shapes and finiteness; return float64 points and unit normals."""
    P = np.asarray(P, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        fail(_FUNC, f"points of shape (N, 3) in '{path}'", f"shape {P.shape}")
    if len(P) == 0:
        fail(_FUNC, f"points in '{path}'", "none (the file holds no points)")
    bad = np.flatnonzero(~np.isfinite(P).all(1))
    if len(bad):
        fail(_FUNC, f"finite points in '{path}'", f"point {bad[0]} = {P[bad[0]].tolist()} ({len(bad)} such points)")
    if N is None:
        return P, None
    N = np.asarray(N, dtype=np.float64)
    if N.shape != P.shape:
        fail(_FUNC, f"one normal per point, shape {P.shape}, in '{path}'", f"normals of shape {N.shape}")
    norm = np.linalg.norm(N, axis=1)
    bad = np.flatnonzero(~(norm > 1e-12) | ~np.isfinite(norm))
    if len(bad):
        fail(_FUNC, f"finite, non-zero normals in '{path}'",
             f"normal {bad[0]} = {N[bad[0]].tolist()} ({len(bad)} such normals)")
    return P, N / norm[:, None]


def _read_text(path):
    """XYZ/PTS text: ``#`` or ``//`` comments, an optional count or header line, 3 or 6 columns."""
    try:
        lines = path.read_text(errors="strict").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        fail(_FUNC, f"a readable text file '{path}'", f"{type(exc).__name__}: {exc}")
    rows = [(k, s) for k, s in ((k, ln.strip()) for k, ln in enumerate(lines, start=1))
            if s and not s.startswith(("#", "//"))]
    if rows:  # a leading point count (PTS) or a column-name header
        tokens = rows[0][1].replace(",", " ").split()
        try:
            [float(t) for t in tokens]
            header = len(tokens) == 1
        except ValueError:
            header = True
        rows = rows[1:] if header else rows
    if not rows:
        fail(_FUNC, f"points in '{path}'", "none (the file holds no points)")
    split = [r.replace(",", " ").split() for _, r in rows]
    width = len(split[0])
    if width not in (3, 6):
        fail(_FUNC, f"3 (x y z) or 6 (x y z nx ny nz) columns in '{path}'",
             f"{width} on line {rows[0][0]} = {rows[0][1]!r}")
    try:
        A = np.array(split, dtype=np.float64).reshape(len(split), width)
    except ValueError:
        k, r = next((k, r) for (k, r), t in zip(rows, split) if not _numbers(t, width))
        fail(_FUNC, f"{width} numbers on every line of '{path}' (as on its first data line)", f"line {k} = {r!r}")
    return A[:, :3], (A[:, 3:] if width == 6 else None)


def _numbers(tokens, width) -> bool:
    try:
        return len([float(t) for t in tokens]) == width
    except ValueError:
        return False


def _read_npz(path):
    try:
        with np.load(path, allow_pickle=False) as data:
            names = sorted(data.files)
            if "points" not in names:
                fail(_FUNC, f"an array 'points' (N, 3) and optional 'normals' (N, 3) in '{path}'", f"arrays {names}")
            P = np.asarray(data["points"], dtype=np.float64)
            N = np.asarray(data["normals"]) if "normals" in names else None
            if "loc" in names or "scale" in names:     # Occupancy Networks / Flow (D-FAUST): normalised points
                P = _denormalise(P, data, names, path)
    except (OSError, EOFError) as exc:
        fail(_FUNC, f"a readable NPZ file '{path}'", f"{type(exc).__name__}: {exc}")
    except ValueError as exc:
        if str(exc).startswith(f"{_FUNC}():"):
            raise
        fail(_FUNC, f"a readable NPZ file '{path}'", f"{type(exc).__name__}: {exc}")
    return P, N


def _denormalise(P, data, names, path):
    """``points * scale + loc``: the frame of an Occupancy Networks NPZ (its points are ``(X - loc) / scale``)."""
    if "loc" not in names or "scale" not in names:
        fail(_FUNC, f"both 'loc' (3,) and 'scale' () with normalised points in '{path}'", f"arrays {names}")
    loc, scale = np.asarray(data["loc"], dtype=np.float64), np.asarray(data["scale"], dtype=np.float64)
    if loc.shape != (3,) or scale.size != 1 or not np.isfinite(loc).all() or not float(scale) > 0:
        fail(_FUNC, f"'loc' of shape (3,) and a finite 'scale' > 0 in '{path}'",
             f"loc of shape {loc.shape}, scale {scale.tolist()}")
    return P * float(scale) + loc


def _read_ply(path):
    """A PLY point cloud ``(P, N or None, None)``, or a PLY mesh ``(None, None, (V, F))``."""
    ply = read_ply(path, _FUNC)
    V, counts, items = ply_polygons(ply, path, _FUNC)
    if len(counts):
        return None, None, (V, fan_triangulate(counts, items)[0])
    vertex = ply["vertex"]
    have = [c in vertex for c in ("nx", "ny", "nz")]
    if any(have) and not all(have):
        fail(_FUNC, f"PLY vertex normals nx, ny, nz all three or none in '{path}'",
             f"only {[c for c, h in zip(('nx', 'ny', 'nz'), have) if h]}")
    N = np.stack([np.asarray(vertex[c], dtype=np.float64) for c in ("nx", "ny", "nz")], 1) if all(have) else None
    return V, N, None


def _sample_mesh(V, F, n_samples, seed, path):
    """Area-weighted uniform samples with the normal of the face they lie on."""
    from mi_loop.mesh.sampling import sample_surface

    n = n_samples if n_samples is not None else max(DEFAULT_SAMPLES, len(V))
    try:
        P, N, _ = sample_surface(V, F, n, seed)
    except ValueError as exc:
        fail(_FUNC, f"a mesh with a positive surface area in '{path}'", str(exc).split(", got ", 1)[-1])
    return P, N
