"""Read the fitting input: oriented point clouds, or meshes sampled into oriented points.

Formats: PLY (vertex-only point clouds with or without ``nx ny nz``, or meshes),
XYZ/PTS/TXT text (3 columns ``x y z`` or 6 columns ``x y z nx ny nz``), NPZ
(``points`` and optional ``normals``), OBJ and OFF meshes. Point clouds without
normals get them from :func:`mi_loop.mesh.points.estimate_normals` (PCA + MST orientation).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["load_oriented_points"]

POINT_SUFFIXES = (".ply", ".xyz", ".pts", ".txt", ".npz", ".obj", ".off")
DEFAULT_SAMPLES = 100_000


def _fail(where: str, message: str):
    raise ValueError(f"{where}: {message}")


def load_oriented_points(path, n_samples: int | None = None, seed: int = 0):
    """Read points and normals from a point-cloud or mesh file.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.ply``, ``.xyz``, ``.pts``, ``.txt``, ``.npz``, ``.obj`` or ``.off`` file.
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
        ``n_file`` (points or vertices in the file), ``n_faces`` (meshes),
        ``n_points`` (returned), ``has_normals``, ``subsampled``, ``seed``.

    Raises
    ------
    ValueError
        Missing or unreadable file, unknown suffix, no points, NaN/Inf points,
        zero-length normals (names the first index), point/normal count
        mismatch, wrong column count, bad ``n_samples``.
    """
    path = Path(path)
    where = f"load_oriented_points: '{path}'"
    suffix = path.suffix.lower()
    if suffix not in POINT_SUFFIXES:
        _fail(where, f"unknown suffix '{path.suffix}', expected one of {', '.join(POINT_SUFFIXES)}")
    if not path.is_file():
        _fail(where, "no such file")
    if n_samples is not None and (isinstance(n_samples, bool) or not isinstance(n_samples, (int, np.integer))
                                  or n_samples < 1):
        _fail(where, f"n_samples must be a positive integer or None, got {n_samples!r}")
    if suffix in (".xyz", ".pts", ".txt"):
        P, N = _read_text(path, where)
        mesh = None
    elif suffix == ".npz":
        P, N = _read_npz(path, where)
        mesh = None
    else:
        P, N, mesh = _read_trimesh(path, where)
    info = {"format": suffix[1:], "seed": int(seed), "subsampled": False}
    if mesh is not None:
        P, N = _sample_mesh(mesh, n_samples, seed, where)
        info.update(kind="mesh", n_file=len(mesh.vertices), n_faces=len(mesh.faces))
    else:
        info.update(kind="points", n_file=len(P))
    P, N = _check_points(P, N, where)
    if mesh is None and n_samples is not None and n_samples < len(P):
        keep = np.sort(np.random.default_rng(seed).choice(len(P), n_samples, replace=False))
        P, N = P[keep], (None if N is None else N[keep])
        info["subsampled"] = True
    info.update(n_points=len(P), has_normals=N is not None)
    return P, N, info


def _check_points(P, N, where):
    """Check shapes and finiteness; return float64 points and unit normals."""
    P = np.asarray(P, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        _fail(where, f"points must have shape (N, 3), got {P.shape}")
    if len(P) == 0:
        _fail(where, "the file holds no points")
    bad = np.flatnonzero(~np.isfinite(P).all(1))
    if len(bad):
        _fail(where, f"point {bad[0]} has a non-finite coordinate {P[bad[0]].tolist()} ({len(bad)} such points)")
    if N is None:
        return P, None
    N = np.asarray(N, dtype=np.float64)
    if N.shape != P.shape:
        _fail(where, f"got {len(P)} points but normals of shape {N.shape}; expected ({len(P)}, 3)")
    norm = np.linalg.norm(N, axis=1)
    bad = np.flatnonzero(~(norm > 1e-12) | ~np.isfinite(norm))
    if len(bad):
        _fail(where, f"normal {bad[0]} is zero-length or non-finite {N[bad[0]].tolist()} ({len(bad)} such normals)")
    return P, N / norm[:, None]


def _read_text(path, where):
    """XYZ/PTS text: ``#`` or ``//`` comments, an optional count or header line, 3 or 6 columns."""
    try:
        lines = path.read_text(errors="strict").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        _fail(where, f"cannot read text ({type(exc).__name__}: {exc})")
    rows = [s for s in (ln.strip() for ln in lines) if s and not s.startswith(("#", "//"))]
    if rows:  # a leading point count (PTS) or a column-name header
        tokens = rows[0].replace(",", " ").split()
        try:
            [float(t) for t in tokens]
            header = len(tokens) == 1
        except ValueError:
            header = True
        rows = rows[1:] if header else rows
    if not rows:
        _fail(where, "the file holds no points")
    try:
        A = np.loadtxt([r.replace(",", " ") for r in rows], dtype=np.float64, ndmin=2)
    except ValueError as exc:
        _fail(where, f"cannot parse the rows as numbers with a fixed column count ({exc})")
    if A.shape[1] not in (3, 6):
        _fail(where, f"expected 3 (x y z) or 6 (x y z nx ny nz) columns, got {A.shape[1]}")
    return A[:, :3], (A[:, 3:] if A.shape[1] == 6 else None)


def _read_npz(path, where):
    try:
        with np.load(path, allow_pickle=False) as data:
            if "points" not in data.files:
                _fail(where, f"expected an array named 'points', found {sorted(data.files)}")
            P = np.asarray(data["points"])
            N = np.asarray(data["normals"]) if "normals" in data.files else None
    except (OSError, EOFError) as exc:
        _fail(where, f"cannot read NPZ ({type(exc).__name__}: {exc})")
    except ValueError as exc:
        if str(exc).startswith(where):
            raise
        _fail(where, f"cannot read NPZ ({exc})")
    if N is not None and len(N) != len(P):
        _fail(where, f"got {len(P)} points but {len(N)} normals")
    return P, N


def _read_trimesh(path, where):
    """PLY/OBJ/OFF through trimesh; returns ``(P, N, None)`` or ``(None, None, mesh)``."""
    import trimesh

    try:
        obj = trimesh.load(str(path), process=False)
    except Exception as exc:  # trimesh raises many types for malformed files
        _fail(where, f"cannot parse ({type(exc).__name__}: {exc})")
    if isinstance(obj, trimesh.Scene):
        parts = list(obj.geometry.values())
        meshes = [g for g in parts if isinstance(g, trimesh.Trimesh) and len(g.faces)]
        if meshes:
            obj = trimesh.util.concatenate(meshes) if len(meshes) > 1 else meshes[0]
        elif parts:
            obj = parts[0]
        else:
            _fail(where, "the file holds no points")
    if isinstance(obj, trimesh.Trimesh) and len(obj.faces):
        return None, None, obj
    P = np.asarray(getattr(obj, "vertices", np.zeros((0, 3))))
    raw = (getattr(obj, "metadata", None) or {}).get("_ply_raw", {})
    data = raw.get("vertex", {}).get("data") if isinstance(raw, dict) else None
    if data is not None and not isinstance(data, dict):                 # binary: structured array
        data = {k: data[k] for k in (data.dtype.names or ())}
    names = set(data) if data is not None else set()
    have = [c in names for c in ("nx", "ny", "nz")]
    if any(have) and not all(have):
        _fail(where, f"PLY vertices have only some of nx, ny, nz: {sorted(names & {'nx', 'ny', 'nz'})}")
    N = np.stack([np.asarray(data[c], dtype=np.float64).ravel() for c in ("nx", "ny", "nz")], 1) \
        if all(have) else None
    if N is not None and len(N) != len(P):
        _fail(where, f"got {len(P)} points but {len(N)} normals")
    return P, N, None


def _sample_mesh(mesh, n_samples, seed, where):
    """Area-weighted uniform samples with the normal of the face they lie on."""
    from mi_loop.mesh.sampling import sample_surface

    V = np.asarray(mesh.vertices, dtype=np.float64)
    bad = np.flatnonzero(~np.isfinite(V).all(1))
    if len(bad):
        _fail(where, f"mesh vertex {bad[0]} has a non-finite coordinate {V[bad[0]].tolist()}")
    n = n_samples if n_samples is not None else max(DEFAULT_SAMPLES, len(V))
    try:
        P, N, _ = sample_surface(V, np.asarray(mesh.faces, dtype=np.int64), n, seed)
    except ValueError as exc:
        _fail(where, str(exc))
    return P, N
