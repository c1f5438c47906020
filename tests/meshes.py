"""Small deterministic test meshes for the subdivision oracles, and the unperturbed tetrahedron.

Every builder returns a :class:`TestMesh`: ``V (n, 3) float64``, ``F (m, 3)
int64`` (consistently oriented), ``creases`` in the mi_loop format (None, an
(c, 2) int array, or (E, sharpness)). Vertex positions are perturbed with a
fixed seed so that no symmetry hides a wrong weight. :data:`MESHES` holds them
all by name (the test ids of the oracle tests).

Kept apart from ``helpers.py``: this is the corpus the subdivision, operator
and energy tests run over (data, not utilities); one module for both would
hold over 600 lines, against the ~400 of the style guide.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class TestMesh:
    """A named test mesh of the subdivision oracles.

    Attributes
    ----------
    name : str
        Unique name (the test id).
    V : (n, 3) float64 NumPy array
        Vertices, perturbed with a fixed seed so that no symmetry hides a wrong weight.
    F : (m, 3) int64 NumPy array
        Consistently oriented triangles.
    creases : None, (c, 2) int NumPy array or ((c, 2) int, (c,) float) tuple
        Creases in the mi_loop format: none, infinitely sharp edges, or edges and sharpness.
    """

    name: str
    V: np.ndarray
    F: np.ndarray
    creases: object = None

    __test__ = False  # not a pytest test class


#: The regular tetrahedron, unperturbed: vertices (float64) and consistently oriented faces.
TET_V = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=float)
TET_F = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])
TET_V.flags.writeable = TET_F.flags.writeable = False     # shared by many tests: never edited in place


def _perturb(V, seed: int, scale: float = 0.1) -> np.ndarray:
    """``V`` plus ``scale`` times standard normal noise drawn with ``seed``."""
    rng = np.random.default_rng(seed)
    return np.asarray(V, dtype=float) + scale * rng.standard_normal(np.shape(V))


def _orient_outward(V, F) -> np.ndarray:
    """Flip faces of a star-shaped closed mesh around the origin to face outward."""
    F = np.array(F, dtype=np.int64)
    for i, (a, b, c) in enumerate(F):
        n = np.cross(V[b] - V[a], V[c] - V[a])
        if np.dot(n, V[a] + V[b] + V[c]) < 0:
            F[i] = (a, c, b)
    return F


def tetrahedron() -> TestMesh:
    """Closed: four valence-3 vertices."""
    F = _orient_outward(TET_V, [[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]])
    return TestMesh("tetrahedron", _perturb(TET_V, 1), F)


def octahedron() -> TestMesh:
    """Closed: six valence-4 vertices."""
    V = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=float)
    F = [[x, y, z] for x in (0, 1) for y in (2, 3) for z in (4, 5)]
    return TestMesh("octahedron", _perturb(V, 2), _orient_outward(V, F))


def _icosahedron_raw():
    """Unperturbed unit icosahedron ``(V, F)``, faces outward."""
    t = (1 + math.sqrt(5)) / 2
    V = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0],
                  [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
                  [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], dtype=float)
    F = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11],
                  [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8],
                  [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9],
                  [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]])
    return V / np.linalg.norm(V[0]), _orient_outward(V, F)


def icosahedron() -> TestMesh:
    """Closed: twelve valence-5 vertices."""
    V, F = _icosahedron_raw()
    return TestMesh("icosahedron", _perturb(V, 3), F)


def bipyramid(n: int) -> TestMesh:
    """Closed: two apexes of valence n next to n equator vertices of valence 4."""
    ang = 2 * math.pi * np.arange(n) / n
    V = np.vstack([np.c_[np.cos(ang), np.sin(ang), np.zeros(n)], [[0, 0, 1.2], [0, 0, -1.2]]])
    F = [[i, (i + 1) % n, n] for i in range(n)] + [[(i + 1) % n, i, n + 1] for i in range(n)]
    return TestMesh(f"bipyramid{n}", _perturb(V, 10 + n, 0.05), _orient_outward(V, F))


def fan_disc(n: int) -> TestMesh:
    """Closed fan: interior centre of valence n, boundary rim with 2 faces per vertex."""
    ang = 2 * math.pi * np.arange(n) / n
    V = np.vstack([[[0, 0, 0]], np.c_[np.cos(ang), np.sin(ang), np.zeros(n)]])
    F = np.array([[0, 1 + i, 1 + (i + 1) % n] for i in range(n)])
    return TestMesh(f"fan_disc{n}", _perturb(V, 30 + n, 0.05), F)


def open_fan(n: int) -> TestMesh:
    """Open fan of n triangles: boundary centre with n faces, two one-face corners."""
    ang = 0.75 * math.pi * np.arange(n + 1) / n
    V = np.vstack([[[0, 0, 0]], np.c_[np.cos(ang), np.sin(ang), np.zeros(n + 1)]])
    F = np.array([[0, 1 + i, 2 + i] for i in range(n)])
    return TestMesh(f"open_fan{n}", _perturb(V, 50 + n, 0.05), F)


def grid_faces(nx: int, ny: int) -> np.ndarray:
    """Faces of a regular triangular lattice of nx by ny vertices (index i + nx j)."""
    F = []
    for j in range(ny - 1):
        for i in range(nx - 1):
            a, b, c, d = i + nx * j, i + 1 + nx * j, i + nx * (j + 1), i + 1 + nx * (j + 1)
            F += [[a, b, c], [b, d, c]]
    return np.array(F)


def lattice_points(nx: int, ny: int, h: float = 1.0) -> np.ndarray:
    """(nx ny, 2) points i h e1 + j h e2 of the lattice with e1 = (1, 0), e2 = (1/2, sqrt3/2).

    With ``grid_faces`` every interior vertex has valence 6 and the
    triangles are equilateral (the diagonal b-c of each quad is the short one).
    """
    i, j = np.meshgrid(np.arange(nx), np.arange(ny))
    i, j = i.ravel(), j.ravel()
    return h * np.c_[i + 0.5 * j, j * math.sqrt(3) / 2]


def _bumpy_lattice(nx: int, ny: int, seed: int) -> np.ndarray:
    """Lattice points of spacing 0.5 lifted to heights 0.2 N(0, 1) drawn with ``seed``."""
    XY = lattice_points(nx, ny, 0.5)
    rng = np.random.default_rng(seed)
    return np.c_[XY, 0.2 * rng.standard_normal(len(XY))]


def grid(nx: int = 6, ny: int = 5) -> TestMesh:
    """Open: a bumpy regular lattice (valence 6 inside, boundary and corners around)."""
    return TestMesh(f"grid{nx}x{ny}", _perturb(_bumpy_lattice(nx, ny, 70), 71, 0.03), grid_faces(nx, ny))


def open_cylinder(n: int = 7, rows: int = 3) -> TestMesh:
    """Open: a twisted cylinder of ``rows`` rings of ``n`` vertices, two boundary loops."""
    ang = 2 * math.pi * np.arange(n) / n
    V = np.vstack([np.c_[np.cos(ang + 0.5 * r * 2 * math.pi / n), np.sin(ang + 0.5 * r * 2 * math.pi / n),
                         np.full(n, 0.8 * r)] for r in range(rows)])
    F = []
    for r in range(rows - 1):
        for i in range(n):
            a, b = r * n + i, r * n + (i + 1) % n
            c, d = (r + 1) * n + i, (r + 1) * n + (i + 1) % n
            F += [[a, b, c], [b, d, c]]
    return TestMesh(f"cylinder{n}", _perturb(V, 80, 0.05), np.array(F))


def icosahedron_cap() -> TestMesh:
    """Icosahedron without one vertex and its 5 faces: open, pentagonal boundary."""
    V, F = _icosahedron_raw()
    drop = 3
    F = F[~np.any(F == drop, axis=1)]
    keep = np.setdiff1d(np.arange(len(V)), [drop])
    remap = -np.ones(len(V), dtype=np.int64)
    remap[keep] = np.arange(len(keep))
    return TestMesh("icosahedron_cap", _perturb(V[keep], 90), remap[F])


def creased_cube() -> TestMesh:
    """Triangulated cube, all 12 cube edges infinitely sharp: 8 corners."""
    V = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    quads = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    F = [[q[0], q[1], q[2]] for q in quads] + [[q[0], q[2], q[3]] for q in quads]
    E = sorted({tuple(sorted((q[i], q[(i + 1) % 4]))) for q in quads for i in range(4)})
    return TestMesh("creased_cube", _perturb(V, 100), _orient_outward(V, F), np.array(E))


def _icosahedron_loop_edges(apex: int = 0) -> np.ndarray:
    """The 5 edges of the pentagon around an icosahedron vertex."""
    _, F = _icosahedron_raw()
    E = [tuple(sorted(set(f) - {apex})) for f in F if apex in f]
    return np.array(sorted(E))


def icosahedron_crease_loop(sharpness=None) -> TestMesh:
    """Icosahedron with a closed crease loop (infinite, or semi-sharp)."""
    V, F = _icosahedron_raw()
    E = _icosahedron_loop_edges()
    if sharpness is None:
        return TestMesh("ico_crease_loop", _perturb(V, 110), F, E)
    s = np.full(len(E), float(sharpness))
    return TestMesh(f"ico_semisharp{sharpness:g}", _perturb(V, 111), F, (E, s))


def icosahedron_dart() -> TestMesh:
    """Icosahedron with an open crease path 0-1-8: darts at 0 and 8."""
    V, F = _icosahedron_raw()
    return TestMesh("ico_dart", _perturb(V, 120), F, np.array([[0, 1], [1, 8]]))


def grid_dart() -> TestMesh:
    """Regular lattice with a crease from the boundary ending at an interior vertex."""
    nx, ny = 7, 6
    E = np.array([[1 + nx * j, 1 + nx * (j + 1)] for j in range(3)])  # ends at vertex 1 + 3 nx
    return TestMesh("grid_dart", _bumpy_lattice(nx, ny, 130), grid_faces(nx, ny), E)


def mixed_sharpness() -> TestMesh:
    """Icosahedron with a crease path of sharpness inf, 1, 2, 3, 4, 2.5 edges."""
    V, F = _icosahedron_raw()
    E = np.array([[0, 1], [1, 8], [8, 3], [3, 2], [2, 10], [10, 0]])
    s = np.array([np.inf, 1.0, 2.0, 3.0, 4.0, 2.0])
    return TestMesh("mixed_sharpness", _perturb(V, 140), F, (E, s))


def grid_semisharp(s: float) -> TestMesh:
    """Regular lattice crossed boundary to boundary by a crease of sharpness ``s``."""
    nx, ny = 7, 6
    E = np.array([[2 + nx * j, 2 + nx * (j + 1)] for j in range(ny - 1)])
    return TestMesh(f"grid_semisharp{s:g}", _bumpy_lattice(nx, ny, 150), grid_faces(nx, ny),
                    (E, np.full(len(E), float(s))))


def all_meshes() -> list:
    """Return every test mesh (closed, open, creased)."""
    meshes = [tetrahedron(), octahedron(), icosahedron()]
    meshes += [bipyramid(n) for n in range(3, 13)]
    meshes += [fan_disc(n) for n in (3, 4, 5, 6, 8)]
    meshes += [open_fan(n) for n in (1, 2, 3, 5)]
    meshes += [grid(), open_cylinder(), icosahedron_cap()]
    meshes += [creased_cube(), icosahedron_crease_loop(), icosahedron_dart(), grid_dart()]
    meshes += [icosahedron_crease_loop(1), icosahedron_crease_loop(2), mixed_sharpness()]
    meshes += [grid_semisharp(1), grid_semisharp(2)]
    return meshes


#: Every test mesh by name.
MESHES = {m.name: m for m in all_meshes()}

