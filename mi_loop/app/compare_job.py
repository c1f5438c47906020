"""The ``mi-loop compare`` job: distances between a fitted surface and a target, with their definitions.

FITTED is a control mesh (its limit surface is measured) or a plain triangle
mesh such as a ``limit.ply``. Without ``--mesh`` or ``--control`` the job
decides by the vertex count: a mesh of more than :data:`CONTROL_VERTEX_LIMIT`
vertices is taken as a plain mesh (evaluating the limit surface of a 64k-vertex
mesh takes minutes and measures a surface nobody fitted), and it says so.
"""
from __future__ import annotations

from pathlib import Path

__all__ = ["CONTROL_VERTEX_LIMIT", "DEFINITIONS", "LEVEL", "run"]

#: Above this many vertices an unmarked FITTED mesh is taken as a plain mesh, not a control mesh.
CONTROL_VERTEX_LIMIT = 20_000
#: Tessellation level of a control mesh's limit surface (4**LEVEL triangles per control face).
LEVEL = 3

#: What every number of the output means, and its unit (also in ``mi-loop compare --help``).
DEFINITIONS = {
    "two_sided": {
        "units": "fractions of the target's bounding-box diagonal (0.01 = 1 % of it); diagonal in the "
                 "target's own units",
        "p2s_mean, p2s_rms, p2s_max": "target to fit: exact point-to-triangle distance from every target "
                                      "point (or 100,000 area-weighted samples of a target mesh) to the "
                                      "fitted surface; mean, root mean square, maximum",
        "s2p_mean, s2p_rms, s2p_max": "fit to target: distance from 100,000 area-weighted samples of the "
                                      "fitted surface to the target surface (to the nearest target point "
                                      "for a point target)",
        "mean": "(p2s_mean + s2p_mean) / 2",
        "rms": "sqrt((p2s_rms^2 + s2p_rms^2) / 2)",
        "hausdorff": "max(p2s_max, s2p_max), the two-sided Hausdorff distance",
        "n_target, n_fit": "target points or samples, and fitted-surface samples, that were measured",
    },
    "nps": {
        "units": "the Neural Parametric Surfaces protocol: both meshes translated by the centre of the "
                 "target's bounding box and scaled by 'scale' so that the target's largest extent is 2; "
                 "distances in those units (the paper prints P2S and HD x 1e3), angles in degrees; "
                 "30,000 area-weighted samples per surface",
        "P2S": "point-to-surface distance: mean of the two one-sided mean distances",
        "HD": "Hausdorff distance: max of the two one-sided maximum distances",
        "NAE": "normal angle error in degrees: mean over both directions of arccos |n_s . n_c|, n_s the "
               "face normal at a sample, n_c the face normal at its closest point on the other surface",
        "NAE_oriented": "the same without the absolute value (penalises flipped normals)",
        "p2s_fit_to_target, p2s_target_to_fit, hd_fit_to_target, hd_target_to_fit": "the one-sided parts",
        "scale": "the factor applied to both meshes",
    },
}

_AS = ("auto", "control", "mesh")


def _fitted_surface(fitted: Path, as_: str, log):
    """The dense surface to measure: ``(V, F, description)``."""
    from mi_loop import io
    from mi_loop.mesh.topology import validate_mesh
    from mi_loop.subdiv.masks import limit_mesh

    V, F = io.read_mesh(fitted)
    if as_ == "auto":
        as_ = "mesh" if len(V) > CONTROL_VERTEX_LIMIT else "control"
        if as_ == "mesh":
            log.say(f"FITTED '{fitted.name}' has {len(V):,} vertices (more than {CONTROL_VERTEX_LIMIT:,}): "
                    "measuring it as a plain triangle mesh; pass --control to evaluate its limit surface")
    if as_ == "mesh":
        return V, F, {"path": str(fitted), "as": "plain triangle mesh", "n_vertices": len(V)}
    V, F, _ = validate_mesh(V, F, f"compare: {fitted}")
    log.say(f"FITTED '{fitted.name}': control mesh of {len(V):,} vertices: evaluating its limit surface at "
            f"level {LEVEL} ({len(F) * 4 ** LEVEL:,} triangles; --mesh measures the file as it is)")
    V_lim, F_lim, _ = limit_mesh(V, F, level=LEVEL)
    return V_lim, F_lim, {"path": str(fitted), "as": f"control mesh (its limit surface at level {LEVEL})",
                          "n_vertices": len(V)}


def run(fitted, target, *, as_: str = "auto", log) -> dict:
    """Distances between FITTED and TARGET.

    Parameters
    ----------
    fitted, target : str or os.PathLike
        The fitted surface (control mesh or plain mesh) and the target (points or mesh).
    as_ : {'auto', 'control', 'mesh'}
        How to read FITTED: by its vertex count, as a control mesh, as a plain mesh.
    log : mi_loop.app.progress.Reporter

    Returns
    -------
    dict
        ``fitted`` (what was measured), ``two_sided`` (:func:`mi_loop.metrics.two_sided`),
        ``nps`` (:func:`mi_loop.metrics.nps_metrics`, target meshes only) and
        ``definitions`` (:data:`DEFINITIONS`).
    """
    from mi_loop import io
    from mi_loop.app.report import plain
    from mi_loop.errors import fail
    from mi_loop.io.points import load_oriented_points
    from mi_loop.metrics import nps_metrics, two_sided

    if as_ not in _AS:
        fail("compare", f"as_ one of {_AS}", as_)
    fitted, target = Path(fitted), Path(target)
    V, F, described = _fitted_surface(fitted, as_, log)
    P, _, info = load_oriented_points(target)
    out = {"fitted": described}
    log.say(f"two-sided distances to '{target.name}' ({info['kind']}; 100,000 samples per surface)")
    if info.get("kind") == "mesh":
        Vt, Ft = io.read_mesh(target)
        out["two_sided"] = two_sided(V, F, Vt, Ft)
        log.say("Neural Parametric Surfaces metrics (30,000 samples per surface)")
        out["nps"] = nps_metrics((V, F), (Vt, Ft))
    else:
        out["two_sided"] = two_sided(V, F, P)
    out["definitions"] = {k: v for k, v in DEFINITIONS.items() if k in out}
    return plain(out)
