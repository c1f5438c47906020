"""Build a control-mesh template: from oriented points (screened Poisson, then
decimation) or from a triangle mesh (refinement, then decimation).

Pipeline of :func:`make_template` (thesis, ch. 5: "screened Poisson
reconstruction, then quadric edge-collapse decimation"):

1. screened Poisson reconstruction (pymeshlab) at a depth chosen from the
   target size (:func:`poisson_depth`);
2. keep the largest connected component (drops Poisson's spurious blobs);
3. quadric edge-collapse decimation to the requested vertex count, keeping
   topology and normals;
4. sliver removal: edge flips, tangential relaxation projected back on the
   Poisson surface, and collapses of needle edges, until every angle is at
   least ``min_angle`` degrees;
5. orientation agreeing with the input normals, and :func:`mi_loop.validate_mesh`.

:func:`mesh_template` starts from a manifold triangle mesh instead (a mesh
frame of a sequence): midpoint refinement to at least three times the target
count, then steps 3-5 with the mesh in place of the Poisson surface. Thin
parts the Poisson octree cannot resolve (a fox's legs and ears at depth 6)
keep their topology and extent.

:func:`feature_template` is the template of a mesh with sharp features (a
CAD part): the mesh's feature curves (:mod:`mi_loop.mesh.features`), a
planar-quadric decimation of the refined mesh, which keeps vertices on the
curves, and the control edges along the curves as infinitely sharp creases.
"""
from __future__ import annotations

import time
from typing import NoReturn

import numpy as np

from mi_loop.fitting.slivers import remove_slivers
from mi_loop.mesh.geometry import connected_components, euler_characteristic, face_areas, largest_component, weld
from mi_loop.mesh.handles import cut_handles
from mi_loop.mesh.topology import validate_mesh

__all__ = ["FEATURE_ANGLE", "feature_template", "make_template", "mesh_template", "poisson_depth"]

#: Dihedral angle in degrees above which a mesh edge is a sharp feature (:func:`feature_template`).
FEATURE_ANGLE = 40.0
#: Feature chains shorter than this share of the bounding-box diagonal are noise.
MIN_FEATURE_LENGTH = 0.05
#: A mesh has sharp features only if three quarters of its edges bend by less than this (degrees).
FAIR_ANGLE = 2.0


def _fail(message: str, func: str = "make_template") -> NoReturn:
    raise ValueError(f"{func}(): {message}")


def poisson_depth(n_vertices: int) -> int:
    """Pick the screened-Poisson octree depth for a template of ``n_vertices``.

    Rule: depth 6 up to 2000 vertices, 7 up to 8000, 8 above. A depth-``d``
    reconstruction of a compact shape has roughly ``3 * 4**d`` vertices
    (bunny scan: 11k at depth 6, 46k at 7, 177k at 8), so the decimation
    ratio stays at 5 or more while the Poisson step stays cheap: each depth
    costs about four times the one below (BENCHMARKS.md, "Bunny scan", has
    depth 8 next to the fits).

    Parameters
    ----------
    n_vertices : int
        Target vertex count.

    Returns
    -------
    depth : int

    Examples
    --------
    >>> poisson_depth(314), poisson_depth(4667), poisson_depth(20000)
    (6, 7, 8)
    """
    return 6 if n_vertices <= 2000 else 7 if n_vertices <= 8000 else 8


def make_template(P, N, n_vertices: int, depth: int | None = None, seed: int = 0,
                  min_angle: float = 10.0, threads: int = 1, max_points: int = 500_000, *,
                  point_weight: float = 4.0, samples_per_node: float = 1.5, zero_normals: str = "raise",
                  genus: int | None = None):
    """Reconstruct a closed manifold triangle control mesh with about ``n_vertices`` vertices.

    Parameters
    ----------
    P : (k, 3) float NumPy array
        Points.
    N : (k, 3) float NumPy array
        Oriented normals (outward), any non-zero length (but see ``zero_normals``).
    n_vertices : int
        Target vertex count, at least 4 and at most ``k // 2``.
    depth : int or None
        Poisson octree depth (4 to 10); None picks :func:`poisson_depth`.
    seed : int
        Seed of the random subset used when ``k > max_points``.
    min_angle : float
        Smallest allowed triangle angle in degrees (0 to 20).
    threads : int
        Poisson threads. One is the default: more threads made pymeshlab's
        Poisson many times slower on small machines, not faster.
    point_weight, samples_per_node : float, optional
        Screened Poisson's screening weight and points per octree node
        (pymeshlab's defaults, 4 and 1.5). Noisy data wants a smoother
        membrane: :func:`mi_loop.fitting.noise.template_options` lowers the
        first and raises the second with the noise level.
    max_points : int
        Inputs larger than this are randomly subsampled before Poisson.
    zero_normals : {'raise', 'drop'}
        What a normal of zero length does: raise (a user's point cloud: say
        to estimate normals), or drop its point (points a program derived,
        such as a visual hull's, where a few may have no orientation);
        ``info["dropped_normals"]`` counts them.
    genus : int or None, optional
        The subject's genus: a closed template with more handles has its shortest handle loops cut
        and capped until it has this many (:func:`mi_loop.mesh.handles.cut_handles`: where a fine
        octree joins two parts that touch, such as an arm resting on the torso). None (default):
        the genus the Poisson surface has.

    Returns
    -------
    V : (n, 3) float64 NumPy array
        Vertices, ``n`` within a few percent of ``n_vertices`` (sliver
        collapses remove a few).
    F : (m, 3) int64 NumPy array
        Triangles of one manifold component (closed unless the Poisson
        surface is open), oriented like the input normals.
    info : dict
        ``depth``, ``n_points``, ``poisson_vertices`` (largest component),
        ``poisson_components``, ``dropped_normals``, ``vertices``, ``faces``, ``genus`` (None if open),
        ``boundary_edges`` (0: closed), ``handles_cut`` (the lengths of the loops cut, normalised units),
        ``min_angle`` (degrees, achieved), ``flips``, ``collapses``,
        ``time_poisson``, ``time_decimate``, ``time_cleanup``, ``time_total``
        (seconds).

    Raises
    ------
    ValueError
        Bad shapes, non-finite values, zero normals (with ``zero_normals='raise'``), ``n_vertices < 4``,
        ``n_vertices > k // 2`` or above half the Poisson mesh's vertex
        count (say to raise ``depth``), bad ``depth``/``min_angle``, or a
        result that still fails :func:`mi_loop.validate_mesh`.

    Notes
    -----
    Poisson closes holes of open scans (e.g. the unscanned bunny bottom)
    with a smooth membrane; nothing is trimmed, so the template is usually
    closed. When the Poisson surface leaves its bounding box (open reliefs
    such as a bust scanned from the front) the template keeps that boundary;
    ``info["boundary_edges"]`` says so. Faces are oriented to agree with the
    input normals (area-weighted, nearest input point per face).
    """
    t0 = time.perf_counter()
    P, N, n_vertices, depth, dropped = _check_inputs(P, N, n_vertices, depth, min_angle, max_points, zero_normals)
    _check_genus(genus, "make_template")
    if len(P) > max_points:
        keep = np.sort(np.random.default_rng(seed).choice(len(P), max_points, replace=False))
        P, N = P[keep], N[keep]
    Vp, Fp, n_comp = _poisson(P, N, depth, threads, point_weight, samples_per_node)
    t1 = time.perf_counter()
    if n_vertices > len(Vp) // 2:
        _fail(f"n_vertices={n_vertices} is more than half the {len(Vp)} vertices of the depth-{depth} "
              f"Poisson surface; pass a larger depth (at most 10)")
    V, F = _decimate(Vp, Fp, n_vertices, euler_characteristic(len(Vp), Fp)[0])
    t2 = time.perf_counter()
    V, F, stats = remove_slivers(V, F, Vp, Fp, min_angle)
    if _agreement(V, F, P, N) < 0:
        F = F[:, ::-1].copy()
    V, F, _ = validate_mesh(V, F, "make_template")
    V, F, loops = _to_genus(V, F, genus, "make_template")
    t3 = time.perf_counter()
    chi, n_boundary = euler_characteristic(len(V), F)
    info = {"depth": depth, "point_weight": float(point_weight), "samples_per_node": float(samples_per_node),
            "n_points": len(P), "dropped_normals": dropped, "poisson_vertices": len(Vp), "poisson_components": n_comp,
            "vertices": len(V), "faces": len(F), "genus": (2 - chi) // 2 if n_boundary == 0 else None,
            "boundary_edges": n_boundary, "handles_cut": loops,
            "min_angle": stats["min_angle"], "flips": stats["flips"], "collapses": stats["collapses"],
            "time_poisson": t1 - t0, "time_decimate": t2 - t1, "time_cleanup": t3 - t2,
            "time_total": t3 - t0}
    return V, F, info


def mesh_template(V, F, n_vertices: int, min_angle: float = 10.0, planar: bool = False, genus: int | None = None):
    """Decimate a manifold triangle mesh to a control mesh of about ``n_vertices`` vertices.

    Parameters
    ----------
    V : (k, 3) float NumPy array
        Vertices of the input mesh.
    F : (m, 3) int NumPy array
        Its triangles: consistently oriented and manifold (boundaries allowed)
        once coincident vertices are merged (a triangle soup is welded first).
        Only the largest connected component is used; it must hold at least
        90 % of the area.
    n_vertices : int
        Target vertex count, at least 4.
    min_angle : float
        Smallest allowed triangle angle in degrees (0 to 20).
    planar : bool
        Refine to nine times the target count and decimate with planar
        quadrics (pymeshlab's ``planarquadric``): the choice for meshes with
        sharp features, whose corners the default cuts (on the fandisk, the
        sliver removal after the default decimation left parts of the mesh
        4.5 % of the diagonal from the template; 0.2 % this way).
    genus : int or None, optional
        As for :func:`make_template`.

    Returns
    -------
    V, F, info
        As :func:`make_template`; ``info`` has ``input_vertices``,
        ``refined_vertices``, ``vertices``, ``faces``, ``genus``,
        ``boundary_edges``, ``handles_cut``, ``min_angle``, ``flips``, ``collapses``,
        ``time_total``.

    Raises
    ------
    ValueError
        The input fails :func:`mi_loop.validate_mesh` (the message says why),
        is in pieces (largest part below 90 % of the area), ``n_vertices < 4``,
        or a bad ``min_angle``.

    Examples
    --------
    >>> from mi_loop.datasets import icosphere
    >>> V, F = icosphere(3)
    >>> Vt, Ft, info = mesh_template(V, F, 200)
    >>> 190 <= len(Vt) <= 210, info["genus"], info["min_angle"] >= 10
    (True, 0, True)
    """
    import pymeshlab

    t0 = time.perf_counter()
    if not int(n_vertices) == n_vertices or n_vertices < 4:
        _fail(f"n_vertices must be an integer >= 4, got {n_vertices!r}", "mesh_template")
    if not 0 <= min_angle <= 20:
        _fail(f"min_angle must be in [0, 20] degrees, got {min_angle!r}", "mesh_template")
    _check_genus(genus, "mesh_template")
    V, F = weld(np.asarray(V, dtype=np.float64), np.asarray(F))
    V, F, _ = validate_mesh(V, F, "mesh_template")
    total = face_areas(V, F).sum()
    V, F = largest_component(V, F)
    share = face_areas(V, F).sum() / total
    if share < 0.9:
        _fail(f"the mesh is in pieces: its largest connected part holds only {100 * share:.0f} % of its area",
              "mesh_template")
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=V, face_matrix=F))
    while ms.current_mesh().vertex_number() < (9 if planar else 3) * n_vertices:
        ms.meshing_surface_subdivision_midpoint(iterations=1, threshold=pymeshlab.PercentageValue(0))
    Vr = np.asarray(ms.current_mesh().vertex_matrix(), dtype=np.float64)
    Fr = np.asarray(ms.current_mesh().face_matrix(), dtype=np.int64)
    chi = euler_characteristic(len(Vr), Fr)[0]
    Vd, Fd = _decimate(Vr, Fr, int(n_vertices), chi, planar)
    Vd, Fd, stats = remove_slivers(Vd, Fd, Vr, Fr, min_angle)
    if len(Vd) < 0.97 * n_vertices:      # sliver collapses took vertices: aim higher once
        Vd, Fd = _decimate(Vr, Fr, 2 * int(n_vertices) - len(Vd), chi, planar)
        Vd, Fd, stats = remove_slivers(Vd, Fd, Vr, Fr, min_angle)
    Vd, Fd, _ = validate_mesh(Vd, Fd, "mesh_template")
    Vd, Fd, loops = _to_genus(Vd, Fd, genus, "mesh_template")
    chi, n_boundary = euler_characteristic(len(Vd), Fd)
    info = {"input_vertices": len(V), "refined_vertices": len(Vr), "vertices": len(Vd), "faces": len(Fd),
            "genus": (2 - chi) // 2 if n_boundary == 0 else None, "boundary_edges": n_boundary,
            "handles_cut": loops,
            "min_angle": stats["min_angle"], "flips": stats["flips"], "collapses": stats["collapses"],
            "time_total": time.perf_counter() - t0}
    return Vd, Fd, info


def _check_genus(genus, func: str) -> None:
    if genus is not None and (isinstance(genus, bool) or not isinstance(genus, (int, np.integer)) or genus < 0):
        _fail(f"genus must be an integer >= 0 or None, got {genus!r}", func)


def _to_genus(V, F, genus, func: str):
    """``(V, F, loop lengths)``: a closed template's handles beyond ``genus`` cut (None, or an open one: as it is)."""
    if genus is None or euler_characteristic(len(V), F)[1]:
        return V, F, []
    V, F, loops = cut_handles(V, F, genus)
    if loops:
        V, F, _ = validate_mesh(V, F, func)
    return V, F, loops


def _check_inputs(P, N, n_vertices, depth, min_angle, max_points, zero_normals):
    P = np.asarray(P, dtype=np.float64)
    N = np.asarray(N, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or N.shape != P.shape:
        _fail(f"P and N must both have shape (k, 3), got {P.shape} and {N.shape}")
    if zero_normals not in ("raise", "drop"):
        _fail(f"zero_normals must be 'raise' or 'drop', got {zero_normals!r}")
    bad = np.flatnonzero(~np.isfinite(P).all(1) | ~np.isfinite(N).all(1))
    if len(bad):
        _fail(f"point or normal {bad[0]} is not finite: {P[bad[0]].tolist()}, {N[bad[0]].tolist()}")
    bad = np.flatnonzero(~(np.linalg.norm(N, axis=1) > 0))
    if len(bad) and zero_normals == "raise":
        _fail(f"normal {bad[0]} has zero length; estimate normals first (mi_loop.mesh.points.estimate_normals)")
    if len(bad):
        P, N = np.delete(P, bad, axis=0), np.delete(N, bad, axis=0)
    if isinstance(n_vertices, bool) or not isinstance(n_vertices, (int, np.integer)) or n_vertices < 4:
        _fail(f"n_vertices must be an integer >= 4, got {n_vertices!r}")
    if n_vertices > len(P) // 2:
        _fail(f"n_vertices={n_vertices} is more than half the {len(P)} input points; the data cannot support it")
    if depth is None:
        depth = poisson_depth(int(n_vertices))
    if isinstance(depth, bool) or not isinstance(depth, (int, np.integer)) or not 4 <= depth <= 10:
        _fail(f"depth must be an integer in [4, 10] or None, got {depth!r}")
    if not 0 <= min_angle <= 20:
        _fail(f"min_angle must be in [0, 20] degrees, got {min_angle!r}")
    if not max_points >= 1000:
        _fail(f"max_points must be at least 1000, got {max_points!r}")
    return P, N / np.linalg.norm(N, axis=1, keepdims=True), int(n_vertices), int(depth), len(bad)


def _poisson(P, N, depth, threads, point_weight=4.0, samples_per_node=1.5):
    """Screened Poisson surface; returns the largest component and the component count."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=P, v_normals_matrix=N))
    ms.generate_surface_reconstruction_screened_poisson(depth=depth, preclean=True, threads=int(threads),
                                                        pointweight=float(point_weight),
                                                        samplespernode=float(samples_per_node))
    mesh = ms.current_mesh()
    V = np.asarray(mesh.vertex_matrix(), dtype=np.float64)
    F = np.asarray(mesh.face_matrix(), dtype=np.int64)
    if len(F) == 0:
        _fail(f"screened Poisson (depth {depth}) returned an empty surface; check the normals' orientation")
    return (*largest_component(V, F), _n_components(V, F))


def _n_components(V, F):
    _, label = connected_components(len(V), F)
    return int(len(np.unique(label[F[:, 0]])))


def _decimate(V, F, n_vertices, chi, planar=False):
    """Quadric edge collapse to ``2 (n - chi)`` faces, i.e. ``n`` vertices on a closed mesh.

    ``planarquadric`` is off unless ``planar``: on the bunny scan it lowered
    the distance of the template's limit surface to the scan by 25-45 %; the
    slivers it leaves are removed afterwards.
    """
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=V, face_matrix=F))
    target = 2 * (n_vertices - chi)
    ms.meshing_decimation_quadric_edge_collapse(
        targetfacenum=int(target), qualitythr=0.3, preservenormal=True, preservetopology=True,
        optimalplacement=True, planarquadric=bool(planar), autoclean=True)
    ms.meshing_remove_unreferenced_vertices()
    mesh = ms.current_mesh()
    return (np.asarray(mesh.vertex_matrix(), dtype=np.float64),
            np.asarray(mesh.face_matrix(), dtype=np.int64))


def _agreement(V, F, P, N):
    """Area-weighted mean of ``n_face . n_point`` over face centroids and their nearest input points."""
    from scipy.spatial import cKDTree

    cross = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    nearest = cKDTree(P).query(V[F].mean(1))[1]
    return float(np.einsum("ij,ij->", cross, N[nearest]))


def feature_template(V, F, n_vertices: int, angle: float = FEATURE_ANGLE, min_angle: float = 10.0):
    """Control mesh of a mesh with sharp features, with its crease edges; None when it has none.

    Parameters
    ----------
    V : (k, 3) float NumPy array
        Vertices of the input mesh.
    F : (m, 3) int NumPy array
        Its triangles (as for :func:`mesh_template`).
    n_vertices : int
        Target vertex count.
    angle : float
        Dihedral angle in degrees above which an edge is a feature.
    min_angle : float
        As for :func:`mesh_template`.

    Returns
    -------
    None, or tuple ``(V_t, F_t, creases, info)``
        None when the mesh has no feature chain of at least
        :data:`MIN_FEATURE_LENGTH` of its diagonal, or when its surface is
        not fair between them: a quarter of its edges or more bend by
        :data:`FAIR_ANGLE` degrees or more (a scan: the 75th percentile of
        the dihedral angles is 7-22 degrees on the organic meshes of the
        test data, where rough triangles make chains of sharp edges; 0.34 on
        the fandisk). Else the template
        (:func:`mesh_template` with ``planar=True``), its crease edges
        (:func:`~mi_loop.mesh.features.crease_edges`, ``(c, 2)`` int64) and
        ``info`` of :func:`mesh_template` plus ``feature_edges``,
        ``feature_curves``, ``feature_length`` (share of the diagonal),
        ``feature_angle`` and ``creases``.

    Raises
    ------
    ValueError
        As :func:`mesh_template`.
    """
    from mi_loop.mesh.features import crease_edges, dihedral_angles, feature_curves

    V = np.asarray(V, dtype=np.float64)
    V, F = weld(V, np.asarray(F))
    V, F, _ = validate_mesh(V, F, "feature_template")
    diag = float(np.linalg.norm(V.max(0) - V.min(0)))
    if np.percentile(dihedral_angles(V, F), 75) >= FAIR_ANGLE:
        return None
    curves = feature_curves(V, F, angle, MIN_FEATURE_LENGTH * diag)
    if curves.n_curves == 0:
        return None
    Vt, Ft, info = mesh_template(V, F, n_vertices, min_angle, planar=True)
    E = crease_edges(Vt, Ft, curves, angle)
    info |= {"feature_edges": len(curves.E), "feature_curves": curves.n_curves,
             "feature_length": curves.length / diag, "feature_angle": float(angle), "creases": len(E)}
    return Vt, Ft, E, info
