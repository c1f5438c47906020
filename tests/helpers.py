"""Helpers shared by the tests: one home for paths, messages, spheres, clouds and conversions.

- paths and constants: :data:`REPO`, :data:`DATA`, :data:`MI_LOOP`, :data:`CAMERA_BOX`;
- messages and processes: :func:`exactly`, :func:`value_error`, :func:`one_line_error`,
  :func:`run_console`, :func:`run_python`;
- spheres, boxes, tori and clouds: :func:`sphere_mesh`, :func:`box_mesh`, :func:`sphere_points`,
  :func:`fibonacci_points`, :func:`torus_cloud`, :func:`torus_error`, :func:`write_xyz`,
  :func:`bunny_in_the_scans_frame`;
- limit surfaces: :func:`limit_surface`, :func:`bbox_diagonal`;
- NumPy and Dr.Jit: :func:`point3f`, :func:`flat`, :func:`as_numpy`;
- GLB files read without mi_loop, the layout rules checked: :func:`parse_glb`, :func:`check_bounds`.

The named meshes of the subdivision oracles are in ``meshes.py``.
Nothing here imports drjit or mitsuba at import time (``conftest.py`` imports
this module before it sets a variant).
"""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

#: Root of the repository.
REPO = Path(__file__).resolve().parent.parent
#: The shared real test data (scans, meshes, sequences), beside the repository.
DATA = REPO.parent / "shared" / "data"
#: The ``mi-loop`` console script of this environment.
MI_LOOP = Path(sys.executable).with_name("mi-loop")
#: Fixed camera box ``(lo, hi)`` of the small renderer tests (multi-view renders, fit_frame).
CAMERA_BOX = (np.full(3, -0.6), np.full(3, 0.6))

# ---------------------------------------------------------------- messages and processes


def exactly(message: str) -> str:
    """Return a ``match`` pattern for exactly ``message`` (one line, nothing before or after).

    Parameters
    ----------
    message : str
        The whole expected message, regular-expression characters included.

    Returns
    -------
    str
        ``"^" + re.escape(message) + "$"``.
    """
    return "^" + re.escape(message) + "$"


def value_error(call, *args, function: str | None = None, **kwargs) -> str:
    """Call ``call(*args, **kwargs)``, expect a one-line ``ValueError`` and return its message.

    Parameters
    ----------
    call : callable
        The function under test.
    *args, **kwargs
        Its arguments.
    function : str, optional
        When given, the message must start with ``"<function>(): expected "``, and
        only the part after ``"<function>(): "`` is returned.

    Returns
    -------
    str
        The message (without the ``function(): `` prefix when ``function`` is given).
    """
    import pytest

    with pytest.raises(ValueError) as info:
        call(*args, **kwargs)
    message = str(info.value)
    assert "\n" not in message, message
    if function is None:
        return message
    assert message.startswith(f"{function}(): expected "), message
    return message[len(f"{function}(): "):]


def one_line_error(capsys, argv, status=1):
    """Run ``mi-loop`` in-process; check the status and a single ``mi-loop: error:`` line; return it.

    Parameters
    ----------
    capsys : pytest fixture
        The calling test's ``capsys``.
    argv : list of str
        Command line after ``mi-loop``.
    status : int, optional
        Expected exit status.

    Returns
    -------
    str
        The error line (progress lines ``[mi-loop ...`` are ignored).
    """
    from mi_loop.app.cli import main

    code = main(argv)
    captured = capsys.readouterr()
    assert code == status, captured.err
    lines = [line for line in captured.err.splitlines() if not line.startswith("[mi-loop")]
    assert len(lines) == 1, captured.err
    assert lines[0].startswith("mi-loop: error: ")
    assert "Traceback" not in captured.err
    return lines[0]


def interrupt_at_frame(monkeypatch, frame):
    """Make ``fit_frame`` (:mod:`mi_loop.fitting.sequence`) raise KeyboardInterrupt when it starts ``frame``,
    as Ctrl-C would."""
    import mi_loop.fitting.sequence

    real = mi_loop.fitting.sequence.fit_frame

    def fake(*args, **kwargs):
        if kwargs.get("frame", args[7] if len(args) > 7 else None) == frame:
            raise KeyboardInterrupt
        return real(*args, **kwargs)
    monkeypatch.setattr(mi_loop.fitting.sequence, "fit_frame", fake)


def run_console(*args, timeout=300) -> subprocess.CompletedProcess:
    """Run the installed ``mi-loop`` console script with ``args``, stdin closed; return the process.

    Parameters
    ----------
    *args : str
        Command line after ``mi-loop``.
    timeout : float, optional
        Seconds before the run is killed.

    Returns
    -------
    subprocess.CompletedProcess
        With text ``stdout`` and ``stderr``; the exit status is not checked.
    """
    return subprocess.run([str(MI_LOOP), *args], capture_output=True, text=True, timeout=timeout,
                          stdin=subprocess.DEVNULL, check=False)


def run_python(code: str, *, timeout=300, **env) -> subprocess.CompletedProcess:
    """Run ``code`` in a fresh interpreter of this environment, in the repository root.

    Parameters
    ----------
    code : str
        Python source, passed with ``-c``.
    timeout : float, optional
        Seconds before the run is killed.
    **env : str
        Environment variables added to (or replacing those of) this process's environment.

    Returns
    -------
    subprocess.CompletedProcess
        With text ``stdout`` and ``stderr``; the exit status is not checked.
    """
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout,
                          cwd=REPO, env={**os.environ, **env})


# ---------------------------------------------------------------- spheres, tori, clouds


def sphere_mesh(radius: float = 1.0, subdivisions: int = 2, *, builder: str = "datasets"):
    """Return an icosphere of ``radius`` at the origin.

    Parameters
    ----------
    radius : float, optional
    subdivisions : int, optional
        Number of 1-to-4 splits of the icosahedron.
    builder : {'datasets', 'trimesh'}, optional
        ``'datasets'``: :func:`mi_loop.datasets.icosphere` scaled by ``radius``
        (midpoint splits, projected onto the sphere once at the end);
        ``'trimesh'``: ``trimesh.creation.icosphere`` (projected at every split:
        other vertices, in another order).

    Returns
    -------
    V : (n, 3) float64 NumPy array
    F : (m, 3) int64 NumPy array
        Outward-oriented triangles.
    """
    if builder == "trimesh":
        import trimesh

        m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
        return np.asarray(m.vertices), np.asarray(m.faces)
    from mi_loop import datasets

    V, F = datasets.icosphere(subdivisions)
    return radius * V, F


def box_mesh(extents=(1.0, 1.0, 1.0)):
    """Return ``trimesh.creation.box``: an axis-aligned box centred at the origin, 12 outward triangles.

    Parameters
    ----------
    extents : (3,) float sequence, optional
        Edge lengths along x, y and z.

    Returns
    -------
    V : (8, 3) float64 NumPy array
    F : (12, 3) int64 NumPy array
    """
    import trimesh

    m = trimesh.creation.box(extents=extents)
    return np.asarray(m.vertices), np.asarray(m.faces)


def sphere_points(n: int, *, radius: float = 1.0, noise: float = 0.0, seed: int = 0):
    """Return ``n`` uniformly random points on a sphere at the origin and their exact normals.

    Parameters
    ----------
    n : int
        Number of points.
    radius : float, optional
    noise : float, optional
        Standard deviation of a radial displacement of each point (the normals stay exact).
    seed : int, optional
        Seed of NumPy's ``default_rng``: directions first, then the displacements.

    Returns
    -------
    P : (n, 3) float64 NumPy array
        ``N * (radius + noise * z)`` with ``z ~ N(0, 1)``; exactly ``N`` for a unit sphere without noise.
    N : (n, 3) float64 NumPy array
        Unit outward normals (the directions).
    """
    rng = np.random.default_rng(seed)
    N = rng.normal(size=(n, 3))
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    return N * (radius + noise * rng.normal(size=(n, 1))), N


def fibonacci_points(n: int) -> np.ndarray:
    """Return ``n`` Fibonacci-spiral points on the unit sphere (evenly spread; also their own normals).

    Parameters
    ----------
    n : int

    Returns
    -------
    (n, 3) float64 NumPy array
    """
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    ang = np.pi * (1 + 5 ** 0.5) * i
    r = np.sqrt(1 - z * z)
    return np.c_[r * np.cos(ang), r * np.sin(ang), z]


def torus_cloud(n: int = 2000, seed: int = 3):
    """Return ``n`` noisy oriented points on :func:`mi_loop.datasets.noisy_torus_points`'s torus, no outliers.

    Parameters
    ----------
    n : int, optional
    seed : int, optional

    Returns
    -------
    P, N : (n, 3) float64 NumPy arrays
        Points and unit normals.
    """
    from mi_loop import datasets

    P, N, _ = datasets.noisy_torus_points(n, outliers=0.0, seed=seed)
    return P, N


def torus_error(V, R: float = 1.0, r: float = 0.4) -> np.ndarray:
    """Return the analytic distance of points to the torus of radii ``(R, r)`` around the z axis.

    Parameters
    ----------
    V : (k, 3) float NumPy array
    R, r : float, optional
        Radius of the centre circle and of the tube.

    Returns
    -------
    (k,) float64 NumPy array
    """
    return np.abs(np.hypot(np.hypot(V[:, 0], V[:, 1]) - R, V[:, 2]) - r)


def write_xyz(path, P, N):
    """Write points and normals as an XYZ text file (``x y z nx ny nz`` per line); return ``path``.

    Parameters
    ----------
    path : pathlib.Path
    P, N : (k, 3) float NumPy arrays
    """
    np.savetxt(path, np.hstack([P, N]))
    return path


def bunny_in_the_scans_frame():
    """Return the bunny range scans and ``control/bunny_314.ply`` mapped box to box onto them.

    Returns
    -------
    P : (k, 3) float64 NumPy array
        The points of ``scans/bunny_rangescans_merged_stride3.ply``.
    V : (314, 3) float64 NumPy array
        The control mesh's vertices, in the scans' frame (same axes, another scale).
    F : (m, 3) int64 NumPy array
    """
    from mi_loop import io

    P, _, _ = io.load_oriented_points(DATA / "scans" / "bunny_rangescans_merged_stride3.ply")
    V, F = io.read_mesh(DATA / "control" / "bunny_314.ply")
    lo, hi = V.min(0), V.max(0)
    return P, P.min(0) + (V - lo) / (hi - lo) * np.ptp(P, axis=0), F


# ---------------------------------------------------------------- limit surfaces


def limit_surface(V, F, level: int = 3):
    """Return the limit-surface points and triangles of control mesh ``(V, F)`` at a tessellation level.

    Parameters
    ----------
    V : (n, 3) float NumPy array
    F : (m, 3) int NumPy array
    level : int, optional

    Returns
    -------
    P : (m 4**level ..., 3) float64 NumPy array
        Exact limit points (SciPy :func:`mi_loop.subdiv.limit.limit_matrix`).
    F_t : (m 4**level, 3) int NumPy array
    """
    from mi_loop.subdiv.limit import limit_matrix
    from mi_loop.subdiv.tessellation import tessellate

    fid, uv, F_t = tessellate(F, level)
    return limit_matrix(F, len(V), fid, uv) @ V, F_t


def bbox_diagonal(V) -> float:
    """Return the length of the bounding-box diagonal of points ``V`` ((k, 3) float NumPy array)."""
    return float(np.linalg.norm(V.max(axis=0) - V.min(axis=0)))


# ---------------------------------------------------------------- NumPy and Dr.Jit


def point3f(A):
    """Return ``(k, 3)`` points as an ``mi.Point3f`` (float32, aligned upload, as a kernel output would be).

    Parameters
    ----------
    A : (k, 3) float array_like

    Returns
    -------
    mi.Point3f (k), without gradients
    """
    import mitsuba as mi

    from mi_loop.ad.upload import upload_vec

    return upload_vec(mi.Point3f, np.asarray(A, dtype=np.float64))


def flat(V, grad: bool = False):
    """Return control points as the flat xyz-interleaved ``mi.Float`` the operators take.

    Parameters
    ----------
    V : (n, 3) float array_like
    grad : bool, optional
        Enable gradients on the result.

    Returns
    -------
    mi.Float (3n), float32
    """
    import drjit as dr
    import mitsuba as mi

    x = mi.Float(np.asarray(V, dtype=np.float32).ravel())
    if grad:
        dr.enable_grad(x)
    return x


def as_numpy(x) -> np.ndarray:
    """Return a Dr.Jit 3-vector array or flat xyz ``mi.Float`` (or its gradient) as ``(k, 3)`` float64.

    Parameters
    ----------
    x : mi.Point3f (k), mi.Vector3f (k) or mi.Float (3k)

    Returns
    -------
    (k, 3) float64 NumPy array
    """
    a = np.array(x, dtype=np.float64)
    return a.reshape(-1, 3) if a.ndim == 1 else a.T

# ---------------------------------------------------------------- GLB files

#: componentType -> (NumPy dtype, bytes); type -> components (glTF 2.0, section 3.6.2).
COMPONENTS = {5125: ("<u4", 4), 5126: ("<f4", 4)}
WIDTHS = {"SCALAR": 1, "VEC3": 3}


def parse_glb(path):
    """Read a GLB file with the specification's layout rules checked; return ``(doc, read)``.

    Written from section 4.4 of the glTF 2.0 specification, without mi_loop's reader: magic,
    version, total length, two chunks of 4-byte multiple lengths, 4-byte aligned buffer views
    inside the buffer, tightly packed accessors.

    Parameters
    ----------
    path : pathlib.Path
        A ``.glb`` file.

    Returns
    -------
    doc : dict
        The JSON chunk.
    read : callable
        ``read(i)``: accessor ``i`` (float32 or uint32) as a ``(count, width)`` NumPy array.
    """
    import json
    import struct

    data = path.read_bytes()
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    assert (magic, version, length) == (b"glTF", 2, len(data))
    json_length, json_type = struct.unpack_from("<II", data, 12)
    assert json_type == 0x4E4F534A and json_length % 4 == 0
    text = data[20:20 + json_length]
    assert text.rstrip(b" ") == text.rstrip()                      # padded with spaces only
    doc = json.loads(text)
    bin_length, bin_type = struct.unpack_from("<II", data, 20 + json_length)
    assert bin_type == 0x004E4942 and bin_length % 4 == 0
    assert 28 + json_length + bin_length == len(data)               # two chunks, nothing else
    chunk = data[28 + json_length:]
    assert doc["buffers"] == [{"byteLength": bin_length}] or doc["buffers"][0]["byteLength"] <= bin_length
    for view in doc["bufferViews"]:
        assert view["buffer"] == 0 and view["byteOffset"] % 4 == 0
        assert view["byteOffset"] + view["byteLength"] <= doc["buffers"][0]["byteLength"]

    def read(i):
        a = doc["accessors"][i]
        dtype, size = COMPONENTS[a["componentType"]]
        view = doc["bufferViews"][a["bufferView"]]
        assert a["count"] * size * WIDTHS[a["type"]] == view["byteLength"]      # tightly packed
        start = view["byteOffset"] + a.get("byteOffset", 0)
        return np.frombuffer(chunk, dtype, a["count"] * WIDTHS[a["type"]], start).reshape(a["count"], -1)
    return doc, read


def check_bounds(doc, read, i):
    """Check that accessor ``i``'s ``min`` and ``max`` are the bounds of its values, as the specification requires.

    Parameters
    ----------
    doc, read
        :func:`parse_glb`'s result.
    i : int
        The accessor.
    """
    a, values = doc["accessors"][i], read(i)
    np.testing.assert_array_equal(a["min"], values.min(axis=0))
    np.testing.assert_array_equal(a["max"], values.max(axis=0))


def blob_capture(directory):
    """Six renders of a smooth coloured blob, 40 x 32, written as a capture in ``directory``; its transforms.json."""
    from mi_loop import datasets
    from mi_loop.io.capture import write_capture
    from mi_loop.io.emitters import DEFAULT_EMITTERS
    from mi_loop.render.cameras import fibonacci_cameras
    from mi_loop.render.captures import render_views
    from mi_loop.subdiv.masks import limit_mesh

    P, F, N = limit_mesh(*datasets.blob(), 2)
    P = (P - P.mean(0)) / np.linalg.norm(P.max(0) - P.min(0))
    cams = fibonacci_cameras(6, [0, 0, 0], 1.9, fov_x_deg=35, width=40, height=32)
    views = render_views(P, F, cams, [dict(e) for e in DEFAULT_EMITTERS], normals=N,
                         colors=np.clip(0.5 + P, 0.1, 0.8), spp=8)
    return write_capture(directory, views)


def slotted_torus(gap: float, n: int = 40_000, R: float = 0.6, r: float = 0.2):
    """Oriented points of a torus tube (radii ``R``, ``r``) cut by a slot ``gap`` wide, with its two end caps.

    The genus says whether a template saw the slot: 0 where it keeps the two ends apart, 1 where
    a coarse octree webs them together (what the default depth does to a body's armpits).
    """
    rng = np.random.default_rng(0)
    half = gap / 2 / R
    phi, theta = rng.uniform(half, 2 * np.pi - half, n), rng.uniform(0, 2 * np.pi, n)
    radial = np.stack([np.cos(phi), np.sin(phi), np.zeros(n)], 1)
    N = np.cos(theta)[:, None] * radial + np.sin(theta)[:, None] * np.array([0.0, 0.0, 1.0])
    P, Ns = [R * radial + r * N], [N]
    for side in (half, -half):           # the caps: disks across the tube, facing into the slot
        m = n // 20
        rho, a = r * np.sqrt(rng.uniform(0, 1, m)), rng.uniform(0, 2 * np.pi, m)
        out, along = np.array([np.cos(side), np.sin(side), 0.0]), np.array([-np.sin(side), np.cos(side), 0.0])
        P.append(R * out + rho[:, None] * (np.cos(a)[:, None] * out + np.sin(a)[:, None] * np.array([0, 0, 1.0])))
        Ns.append(np.tile(-np.sign(side) * along, (m, 1)))
    return np.vstack(P), np.vstack(Ns)


def genus(V, F) -> int:
    """The genus of a closed triangle mesh (asserted closed)."""
    from mi_loop.mesh.geometry import euler_characteristic

    chi, boundary = euler_characteristic(len(V), F)
    assert boundary == 0
    return (2 - chi) // 2


#: The slotted torus's three template runs: the default depth, depth 8, the handles cut to genus 0.
SLOT_RUNS = [("default", []), ("depth 8", ["--template-depth", "8"]), ("genus 0", ["--template-genus", "0"])]


def slot_template_runs(tmp_path, capsys, run, control: str):
    """Fit a torus cut by a 3 % slot under :data:`SLOT_RUNS`: ``{name: (genus of control, stderr)}``.

    ``run(input, out, flags)`` runs the command; ``control`` is the control mesh's path in ``out``.
    """
    from mi_loop import io

    P, N = slotted_torus(0.03)
    np.savetxt(tmp_path / "0000.xyz", np.hstack([P, N]))
    found = {}
    for name, flags in SLOT_RUNS:
        out = tmp_path / name.replace(" ", "")
        run(tmp_path / "0000.xyz", out, flags)
        found[name] = (genus(*io.read_mesh(out / control)), capsys.readouterr().err)
    return found
