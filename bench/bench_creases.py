"""mi_loop against OpenSubdiv (adobe-lagrange) under every rule of the crease model lagrange can express.

For each case of ``tests/subdiv/test_oracle_opensubdiv.py`` (fractional and
large edge sharpness, vertex sharpness, the three boundary rules, darts,
holes; uniform creasing: lagrange has no Chaikin option), at ``L`` steps,
enough for every semi-sharp tag to expire:

* refined points: mi_loop's ``L`` subdivision steps against OpenSubdiv's
  refinement (both exact there);
* limit points: ``mi_loop.limit_matrix`` at the refined vertices' parameters
  against OpenSubdiv's limit evaluation of the same vertices. Darts are
  listed apart: OpenSubdiv evaluates them with the smooth mask, which is not
  their limit (mi_loop takes the dominant eigenvector of the local matrix).

Errors are max |difference| / largest bounding-box side of the control mesh.

Usage::

    PYTHONPATH=. .venv/bin/python bench/bench_creases.py
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "tests" / "subdiv")]

import test_oracle_opensubdiv as t  # noqa: E402  (the cases and the lagrange calls of the tests)

import mi_loop  # noqa: E402
from mi_loop.mesh.topology import sharp_topology  # noqa: E402
from mi_loop.subdiv.subdivision import subdivide_topology  # noqa: E402


def mi_loop_refined(mesh, L, kw):
    """mi_loop's ``L`` steps: composed matrix."""
    topo = sharp_topology(mesh.F, len(mesh.V), "bench", kw.get("creases"), kw.get("corners"),
                          kw.get("boundary", "edge_and_corner"))
    S_total = None
    for _ in range(L):
        S, topo = subdivide_topology(topo)
        S_total = S if S_total is None else S @ S_total
    return S_total


def main():
    rows = []
    worst = {"refined": 0.0, "limit": 0.0, "dart": 0.0}
    for name, (mesh, kw) in t.CASES.items():
        L = t.n_levels_of(kw)
        h = t.oracle_hierarchy(mesh, L, **kw)
        refined, faces = t.lagrange_refine(mesh.V, mesh.F, L, **kw)
        to_oracle = t.match_vertices(refined, faces, h, h.S_total[-1] @ mesh.V)
        used = to_oracle >= 0
        if not used.any():                       # every face a hole (a lone fan under 'none')
            rows.append((name, L, 0, np.nan, np.nan, np.nan))
            continue
        scale = np.ptp(mesh.V, axis=0).max()
        # mi_loop numbers fine vertices its own way: match its refined points to the oracle's by position
        Q_ml = mi_loop_refined(mesh, L, kw) @ mesh.V
        Q_or = h.S_total[-1] @ mesh.V
        nearest = np.linalg.norm(Q_or[:, None] - Q_ml[None], axis=2).argmin(1)
        e_ref = np.abs(refined[used] - Q_ml[nearest[to_oracle[used]]]).max() / scale
        # limit: each refined vertex at one of its (control face, u, v) labels
        P_osd, _ = t.lagrange_refine(mesh.V, mesh.F, L, limit=True, **kw)
        level = h.levels[-1]
        holes = set(h.holes.tolist())
        idx, fid, uv, dart = [], [], [], []
        for i in np.flatnonzero(used):
            lab = {f: p for f, p in level.label[to_oracle[i]].items() if f not in holes}
            if not lab:
                continue
            f = min(lab)
            idx.append(i)
            fid.append(f)
            uv.append(lab[f])
            dart.append(level.vertex_kind(to_oracle[i]) == "dart")
        W = mi_loop.limit_matrix(mesh.F, len(mesh.V), np.array(fid), np.array(uv, dtype=float), **kw)
        d = np.abs(P_osd[idx] - W @ mesh.V).max(1) / scale
        dart = np.array(dart)
        e_lim = float(d[~dart].max()) if (~dart).any() else 0.0
        e_dart = float(d[dart].max()) if dart.any() else float("nan")
        worst["refined"] = max(worst["refined"], e_ref)
        worst["limit"] = max(worst["limit"], e_lim)
        if dart.any():
            worst["dart"] = max(worst["dart"], e_dart)
        rows.append((name, L, int(used.sum()), e_ref, e_lim, e_dart))
    print(f"{'case':34s} {'L':>2s} {'points':>7s} {'refined':>9s} {'limit':>9s} {'darts':>9s}")
    for name, L, n, a, b, c in rows:
        print(f"{name:34s} {L:2d} {n:7d} {a:9.1e} {b:9.1e} {c:9.1e}")
    print(f"worst over {len(rows)} cases: refined {worst['refined']:.1e}, limit (no darts) {worst['limit']:.1e}, "
          f"darts (OpenSubdiv's smooth mask) {worst['dart']:.1e}")


if __name__ == "__main__":
    main()
