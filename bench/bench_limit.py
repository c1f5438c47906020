"""Benchmark the exact Loop limit operator against OpenSubdiv (via adobe-lagrange).

First what a user calls (``--part public``): on the icosphere with permuted
labels and faces, at its level-5 dyadic points shuffled, ``limit_matrix`` for
positions and both derivatives (three calls, and one call with
``derivative=(None, 'u', 'v')``), :class:`mi_loop.LimitOperator`'s build and
Dr.Jit apply, OpenSubdiv's limit positions and normals of the same points, and
a copy of the operator's bytes, all in one process.

Then, by step (``--part operator``), on two control meshes (trimesh icosphere level 3 and a decimated
armadillo) and two sample sets each (a uniform tessellation and random
``(face, u, v)``):

* build of :class:`mi_loop.LimitOperator` (positions + d/du + d/dv), split into
  hierarchy/patch tables, sample rows and the composed subdivision matrix;
* ``op.matrix()`` (composed SciPy CSR) and its apply ``W @ V``;
* Dr.Jit apply, kernels compiled: forward and forward+backward;
* OpenSubdiv uniform limit evaluation (``lagrange.subdivision.subdivide_mesh``)
  at the same dyadic points, and its distance to mi_loop's limit points.

Every figure is min / median / max over ``--runs`` runs, in ms.

Usage::

    .venv/bin/python bench/bench_limit.py            # ~1M samples, 5 runs
    .venv/bin/python bench/bench_limit.py --quick    # 100k samples, 2 runs
"""
from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ARMADILLO = Path(__file__).resolve().parents[2] / "shared" / "data" / "static" / "armadillo.obj"


# -- helpers -------------------------------------------------------------------
def timed(fn, runs: int, warmup: int = 0):
    """Run ``fn`` ``warmup + runs`` times; return (ms list of timed runs, last result)."""
    out = None
    for _ in range(warmup):
        out = fn()
    ts = []
    for _ in range(runs):
        t0 = time.perf_counter()
        out = fn()
        ts.append(1e3 * (time.perf_counter() - t0))
    return ts, out


def stats(ts):
    return float(np.min(ts)), float(np.median(ts)), float(np.max(ts))


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def code_version() -> str:
    """Git commit of the repository and the mi_loop/ files with uncommitted changes."""
    import subprocess

    try:
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                             text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "mi_loop"], cwd=ROOT,
                               capture_output=True, text=True, check=True).stdout.strip()
        files = [line.split()[-1].removeprefix("mi_loop/") for line in dirty.splitlines()]
        return rev + (f" (uncommitted: {', '.join(files)})" if files else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def load() -> str:
    return "load avg " + " / ".join(f"{x:.2f}" for x in os.getloadavg())


# -- meshes and samples --------------------------------------------------------
def icosphere():
    import trimesh

    m = trimesh.creation.icosphere(3)
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)


def armadillo(target_faces: int = 10000):
    """Quadric edge-collapse decimation of the armadillo; checked closed and manifold."""
    import pymeshlab
    import trimesh

    from mi_loop import validate_mesh

    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(ARMADILLO))
    ms.meshing_decimation_quadric_edge_collapse(targetfacenum=target_faces, preservetopology=True,
                                                preservenormal=True, qualitythr=0.3)
    ms.meshing_remove_unreferenced_vertices()
    V, F = ms.current_mesh().vertex_matrix(), ms.current_mesh().face_matrix().astype(np.int64)
    V, F, _ = validate_mesh(V, F)
    tm = trimesh.Trimesh(V, F, process=False)
    if not (tm.is_watertight and tm.is_winding_consistent):
        raise RuntimeError("armadillo: decimated mesh is not closed and consistently oriented")
    return np.asarray(V, float), F


def n_tess_points(n, F, level):
    """Number of points of ``mi_loop.tessellate(F, level)`` on a closed mesh."""
    R = 2 ** level
    n_edges = 3 * len(F) // 2
    return n + n_edges * (R - 1) + len(F) * (R - 1) * (R - 2) // 2


def uniform_level(n, F, target):
    levels = range(0, 9)
    return min(levels, key=lambda L: abs(np.log(n_tess_points(n, F, L) / target)))


def random_samples(m, k, seed=0):
    rng = np.random.default_rng(seed)
    uv = rng.random((k, 2))
    flip = uv.sum(1) > 1
    uv[flip] = 1 - uv[flip]
    return rng.integers(0, m, k), uv


# -- measurements ----------------------------------------------------------------
def bench_build(V, F, fid, uv, runs, res):
    from mi_loop import LimitOperator
    from mi_loop.subdiv.hierarchy import build_hierarchy
    from mi_loop.subdiv.limit import check_samples, level_rows

    n = len(V)
    # One untimed warm-up per step: the first large allocations page-fault.
    res["hierarchy"] = stats(timed(lambda: build_hierarchy(F, n), runs, warmup=1)[0])
    h = build_hierarchy(F, n)
    f, u = check_samples(fid, uv, len(F), "bench")
    res["rows"] = stats(timed(lambda: level_rows(h, f, u, (None, "u", "v")), runs, warmup=1)[0])
    res["composed S_L"] = stats(timed(h.composed, runs)[0])
    res["op build (P)"] = stats(timed(lambda: LimitOperator(F, n, fid, uv, derivatives=False), runs,
                                                   warmup=1)[0])
    ts, op = timed(lambda: LimitOperator(F, n, fid, uv), runs, warmup=1)
    res["op build (P,du,dv)"] = stats(ts)
    ts, W = timed(op.matrix, runs, warmup=1)
    res["op.matrix()"] = stats(ts)
    res["nnz W"] = W.nnz
    res["scipy W @ V"] = stats(timed(lambda: W @ V, runs, warmup=1)[0])
    return op, W


def bench_drjit(op, V, runs, res):
    import drjit as dr
    import mitsuba as mi

    k = op.n_samples
    rng = np.random.default_rng(1)
    w = [mi.Vector3f(rng.standard_normal((3, k)).astype(np.float32)) for _ in range(3)]
    x0 = mi.Float(V.astype(np.float32).ravel())
    dr.eval(w, x0)

    def fwd_pos():
        P = op.positions(x0)
        dr.eval(P)
        dr.sync_thread()

    def fwd_all():
        out = op.evaluate(x0)
        dr.eval(out)
        dr.sync_thread()

    def fwd_bwd(full):
        def run():
            x = mi.Float(x0)
            dr.enable_grad(x)
            if full:
                P, du, dv = op.evaluate(x)
                loss = dr.sum(dr.dot(P, w[0]) + dr.dot(du, w[1]) + dr.dot(dv, w[2]))
            else:
                loss = dr.sum(dr.dot(op.positions(x), w[0]))
            dr.backward(loss)
            g = dr.grad(x)
            dr.eval(g)
            dr.sync_thread()
            return g
        return run

    t0 = time.perf_counter()
    fwd_all()                       # uploads the index/weight arrays, compiles
    res["dr first call"] = 1e3 * (time.perf_counter() - t0)
    res["dr fwd P"] = stats(timed(fwd_pos, runs, warmup=2)[0])
    res["dr fwd P,du,dv"] = stats(timed(fwd_all, runs, warmup=2)[0])
    res["dr fwd+bwd P"] = stats(timed(fwd_bwd(False), runs, warmup=2)[0])
    ts, g = timed(fwd_bwd(True), runs, warmup=2)
    res["dr fwd+bwd P,du,dv"] = stats(ts)
    # The bandwidth yardstick of the issue: NumPy copying the operator's bytes (non-zeros x 8) once, into a
    # buffer allocated once (a fresh one each time adds its page faults: 4-8 ms for the same copy here).
    res["memcpy nnz x 8 B"] = copy_time(2 * res["nnz W"], runs)
    res["fwd+bwd P / memcpy"] = res["dr fwd+bwd P"][1] / res["memcpy nnz x 8 B"][1]
    return g


def copy_time(n_floats: int, runs: int):
    """(min, median, max) ms of copying ``n_floats`` float32 into an allocated buffer (4x the runs: noisy)."""
    src, dst = np.ones(n_floats, dtype=np.float32), np.zeros(n_floats, dtype=np.float32)
    return stats(timed(lambda: np.copyto(dst, src), 4 * runs, warmup=2)[0])


def lagrange_mesh(V, F, linear=False):
    import lagrange

    m = lagrange.SurfaceMesh()
    m.add_vertices(np.ascontiguousarray(V, float))
    m.add_triangles(np.ascontiguousarray(F, np.uint32))
    aid = None
    if linear:
        aid = m.create_attribute("lin", element=lagrange.AttributeElement.Vertex,
                                 usage=lagrange.AttributeUsage.Vector, initial_values=V.copy())
    return m, aid


def bench_lagrange(V, F, level, runs, res):
    import lagrange

    sub = lagrange.subdivision
    m, _ = lagrange_mesh(V, F)
    kw = dict(num_levels=level, scheme=sub.SchemeType.Loop, use_limit_surface=True)
    ts, out = timed(lambda: sub.subdivide_mesh(m, **kw), runs, warmup=1)
    res["osd limit (P)"] = stats(ts)
    res["osd points"] = out.num_vertices
    ts, _ = timed(lambda: sub.subdivide_mesh(m, output_limit_normals="N", output_limit_tangents="T",
                                             output_limit_bitangents="B", **kw), runs, warmup=1)
    res["osd limit (P,T,B,N)"] = stats(ts)


def compare_lagrange(V, F, level, fid, uv, op, res):
    """Max distance between OpenSubdiv's uniform limit points and mi_loop's, / bbox diagonal.

    Points are matched through a linearly interpolated copy of the control
    positions: it equals the control-face point ``(1-u-v) V0 + u V1 + v V2``.
    """
    import lagrange
    from scipy.spatial import cKDTree

    sub = lagrange.subdivision
    m, aid = lagrange_mesh(V, F, linear=True)
    selected = sub.InterpolatedAttributesSelection.Selected
    out = sub.subdivide_mesh(m, num_levels=level, scheme=sub.SchemeType.Loop, use_limit_surface=True,
                             interpolated_attributes_selection=selected,
                             interpolated_linear_attributes=[aid], output_limit_normals="N",
                             output_limit_tangents="T")
    P_osd, lin, N_osd = out.vertices, out.attribute("lin").data, out.attribute("N").data
    diag = np.linalg.norm(V.max(0) - V.min(0))
    bary = np.stack([1 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]], 1)
    X = np.einsum("kc,kcd->kd", bary, V[F[fid]])
    dist, j = cKDTree(X).query(lin)
    if dist.max() > 1e-9 * diag or len(np.unique(j)) != len(j) or len(j) != len(X):
        raise RuntimeError(f"compare_lagrange: could not match points (max {dist.max():.2e})")
    Q = op.matrix() @ V
    Du, Dv = op.matrix("u") @ V, op.matrix("v") @ V
    N = np.cross(Du, Dv)
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    Nn = N_osd / np.linalg.norm(N_osd, axis=1, keepdims=True)
    err = np.linalg.norm(P_osd - Q[j], axis=1) / diag
    ang = np.degrees(np.arccos(np.clip(np.abs(np.sum(Nn * N[j], 1)), 0, 1)))
    val = np.bincount(F.ravel(), minlength=len(V))
    near = (val[F[fid[j]]] != 6).any(1)          # point in a control face with an irregular corner
    res["osd vs mi_loop: max |dP| / diag (all)"] = float(err.max())
    key = "osd vs mi_loop: max |dP| / diag"
    res[f"{key} (irregular faces)"] = float(err[near].max()) if near.any() else 0.0
    res[f"{key} (regular faces)"] = float(err[~near].max()) if (~near).any() else 0.0
    res["osd vs mi_loop: max |dP| / diag (control vertices)"] = float(err[j < len(V)].max())
    res["osd vs mi_loop: normal angle max (deg)"] = float(ang.max())
    res["points in irregular faces"] = int(near.sum())
    T = out.attribute("T").data           # OpenSubdiv's tangents: float32 values stored as float64?
    res["osd tangents float32-exact (fraction)"] = float(np.mean(T.astype(np.float32) == T))


# -- the vertex limit and ARAP on the thesis's control meshes ---------------------------
CONTROL = Path(__file__).resolve().parents[2] / "shared" / "data" / "control"
#: The thesis code's limit Jacobian at the control vertices on this machine class (BRIEF): seconds.
THESIS_VERTEX_LIMIT = {"bunny_4667": 17.4, "lucy_8002": 63.6}


def bench_vertex(runs):
    """limit_positions / limit_masks / limit_matrix at the corners, and ARAP rotations, on bunny_4667, lucy_8002."""
    print(f"\n## vertex limit and ARAP rotations ({load()})")
    print("| mesh | limit_positions ms | limit_masks ms | limit_matrix at corners ms | tangent_masks ms "
          "| thesis s | speed-up (limit_masks) | ARAP rotations ms | SVD rotations ms | covariances ms |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, thesis in THESIS_VERTEX_LIMIT.items():
        print(_vertex_row(name, thesis, runs))


def _vertex_row(name, thesis, runs):
    import trimesh

    import mi_loop
    from mi_loop.energies.arap import ARAP
    from mi_loop.energies.rotations import svd_rotations
    from mi_loop.subdiv.masks import tangent_masks, vertex_samples

    m = trimesh.load(CONTROL / f"{name}.ply", process=False)
    V, F = np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces)
    n = len(V)
    fid, uv = vertex_samples(F, n)
    pos = stats(timed(lambda: mi_loop.limit_positions(V, F), runs, warmup=1)[0])
    masks = stats(timed(lambda: mi_loop.limit_masks(F, n), runs, warmup=1)[0])
    corners = stats(timed(lambda: mi_loop.limit_matrix(F, n, fid, uv), runs, warmup=1)[0])
    tangents = stats(timed(lambda: tangent_masks(F, n), max(1, runs // 2))[0])
    arap = ARAP(V, F)
    V2 = V + 0.01 * np.linalg.norm(V.max(0) - V.min(0)) * np.random.default_rng(0).normal(size=V.shape)
    rot = stats(timed(lambda: arap.rotations(V2), 10 * runs, warmup=2)[0])
    S = arap.covariances(V2)
    svd = stats(timed(lambda: svd_rotations(S), 10 * runs, warmup=2)[0])
    cov = stats(timed(lambda: arap.covariances(V2), 10 * runs, warmup=2)[0])
    return (f"| {name} | {pos[1]:.1f} | {masks[1]:.1f} | {corners[1]:.1f} | {tangents[1]:.0f} | {thesis} "
            f"| {1e3 * thesis / masks[1]:.0f}x | {rot[1]:.2f} | {svd[1]:.2f} | {cov[1]:.2f} |")


# -- the public API on shuffled samples, next to OpenSubdiv ---------------------------
def shuffled_icosphere(level: int, seed: int = 0):
    """The icosphere with permuted vertex labels and faces, and its level-``level`` dyadic points shuffled.

    What a user's mesh and samples look like: no locality in the labels and
    none in the sample order. The points are those of OpenSubdiv's uniform
    limit evaluation at ``level``.
    """
    import mi_loop

    V, F = icosphere()
    rng = np.random.default_rng(seed)
    relabel = rng.permutation(len(V))
    Vp = np.empty_like(V)
    Vp[relabel] = V
    Fp = relabel[F][rng.permutation(len(F))]
    fid, uv, _ = mi_loop.tessellate(Fp, level)
    order = rng.permutation(len(fid))
    return Vp, Fp, fid[order], uv[order]


def bench_public(runs, level=5, lagrange_peer=True):
    """``limit_matrix`` for P, d/du, d/dv (three calls and one), OpenSubdiv and the Dr.Jit apply, in one process."""
    import drjit as dr

    import mi_loop

    V, F, fid, uv = shuffled_icosphere(level)
    n, k = len(V), len(fid)
    print(f"\n## public API: icosphere(3), {n} control vertices, labels and faces permuted; "
          f"{k:,} level-{level} points shuffled  ({load()})")
    res = {}
    three = lambda: [mi_loop.limit_matrix(F, n, fid, uv, derivative=d) for d in (None, "u", "v")]  # noqa: E731
    one = lambda: mi_loop.limit_matrix(F, n, fid, uv, derivative=(None, "u", "v"))                 # noqa: E731
    res["limit_matrix x3 (None, u, v)"] = stats(timed(three, runs, warmup=1)[0])
    ts, mats = timed(one, runs, warmup=1)
    res["limit_matrix (None, u, v)"] = stats(ts)
    res["limit_matrix (None)"] = stats(timed(lambda: mi_loop.limit_matrix(F, n, fid, uv), runs, warmup=1)[0])
    ts, op = timed(lambda: mi_loop.LimitOperator(F, n, fid, uv), runs, warmup=1)
    res["LimitOperator build"] = stats(ts)
    res["nnz W"] = mats[0].nnz
    res["nnz W (P, du, dv)"] = sum(M.nnz for M in mats)
    if lagrange_peer:
        import lagrange

        sub = lagrange.subdivision
        m, _ = lagrange_mesh(V, F)
        kw = dict(num_levels=level, scheme=sub.SchemeType.Loop, use_limit_surface=True, output_limit_normals="N")
        ts, out = timed(lambda: sub.subdivide_mesh(m, **kw), runs, warmup=1)
        res["osd limit (P,N)"] = stats(ts)
        if out.num_vertices != k:
            raise RuntimeError(f"bench_public: OpenSubdiv gave {out.num_vertices} points, not {k}")
        res["limit_matrix (None, u, v) / osd (P,N)"] = res["limit_matrix (None, u, v)"][1] / res["osd limit (P,N)"][1]
        res["limit_matrix x3 / osd (P,N)"] = res["limit_matrix x3 (None, u, v)"][1] / res["osd limit (P,N)"][1]
    bench_drjit(op, V, runs, res)
    res["memcpy nnz(P,du,dv) x 8 B"] = copy_time(2 * res["nnz W (P, du, dv)"], runs)
    res["fwd+bwd P,du,dv / memcpy"] = res["dr fwd+bwd P,du,dv"][1] / res["memcpy nnz(P,du,dv) x 8 B"][1]
    res["drjit threads"] = dr.thread_count()
    report("public API, shuffled", k, res)


# -- report ----------------------------------------------------------------------
TIMED = ["limit_matrix x3 (None, u, v)", "limit_matrix (None, u, v)", "limit_matrix (None)", "LimitOperator build",
         "osd limit (P,N)", "memcpy nnz(P,du,dv) x 8 B", "hierarchy", "rows", "composed S_L", "op build (P)",
         "op build (P,du,dv)", "op.matrix()",
         "scipy W @ V", "dr fwd P", "dr fwd P,du,dv", "dr fwd+bwd P", "dr fwd+bwd P,du,dv", "memcpy nnz x 8 B",
         "osd limit (P)", "osd limit (P,T,B,N)"]

PER_MESH = {"hierarchy", "composed S_L"}   # independent of the samples


def report(name, k, res):
    print(f"\n### {name}: {k:,} samples   ({load()})")
    print(f"| {'step':<22} | {'min ms':>9} | {'median ms':>9} | {'max ms':>9} | {'median ms / 1M':>14} |")
    print(f"|{'-' * 24}|{'-' * 11}|{'-' * 11}|{'-' * 11}|{'-' * 16}|")
    for key in TIMED:
        if key in res:
            lo, med, hi = res[key]
            per = "-" if key in PER_MESH else f"{med * 1e6 / k:.1f}"
            print(f"| {key:<22} | {lo:9.1f} | {med:9.1f} | {hi:9.1f} | {per:>14} |")
    for key, val in res.items():
        if key not in TIMED:
            print(f"  {key}: {val:.3g}" if isinstance(val, float) else f"  {key}: {val:,}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="100k samples, 2 runs")
    ap.add_argument("--samples", type=int, default=None, help="target sample count (default 1M)")
    ap.add_argument("--runs", type=int, default=None, help="timed runs per figure (default 5)")
    ap.add_argument("--no-lagrange", action="store_true", help="skip the OpenSubdiv comparison")
    ap.add_argument("--mesh", choices=["icosphere", "armadillo"], action="append",
                    help="restrict to one mesh (repeatable)")
    ap.add_argument("--part", choices=["public", "operator", "vertex"], action="append",
                    help="public (limit_matrix and LimitOperator on shuffled samples against OpenSubdiv), operator "
                         "(build and apply, by step) and/or vertex (vertex limit, ARAP rotations); default all three")
    args = ap.parse_args()
    target = args.samples or (100_000 if args.quick else 1_000_000)
    runs = args.runs or (2 if args.quick else 5)

    if not args.no_lagrange:
        # Before pymeshlab: it loads an older libtbb that lacks symbols lagrange needs.
        import lagrange  # noqa: F401
    import drjit as dr
    import mitsuba as mi

    import mi_loop

    mi_loop.set_variant("llvm_ad_rgb")
    print(f"# bench_limit  {time.strftime('%Y-%m-%d %H:%M')}  nproc={os.cpu_count()}  "
          f"cpu={cpu_model()}  drjit threads={dr.thread_count()}  mitsuba {mi.__version__}  "
          f"drjit {dr.__version__}  mi_loop {code_version()}  runs={runs}  {load()}")
    parts = args.part or ["public", "operator", "vertex"]
    if "public" in parts:
        bench_public(runs, lagrange_peer=not args.no_lagrange)
    if "vertex" in parts:
        bench_vertex(runs)
    meshes = {"icosphere": icosphere, "armadillo": armadillo}
    for mesh_name in (args.mesh or list(meshes)) if "operator" in parts else []:
        t0 = time.perf_counter()
        V, F = meshes[mesh_name]()
        print(f"\n## {mesh_name}: {len(V)} vertices, {len(F)} faces "
              f"(valence != 6: {int((np.bincount(F.ravel()) != 6).sum())} vertices; "
              f"load {1e3 * (time.perf_counter() - t0):.0f} ms)")
        L = uniform_level(len(V), F, target)
        fid_u, uv_u, _ = mi_loop.tessellate(F, L)
        fid_r, uv_r = random_samples(len(F), target)
        for label, fid, uv in ((f"uniform level {L}", fid_u, uv_u), ("random", fid_r, uv_r)):
            res = {}
            op, _ = bench_build(V, F, fid, uv, runs, res)
            bench_drjit(op, V, runs, res)
            if label.startswith("uniform") and not args.no_lagrange:
                bench_lagrange(V, F, L, runs, res)
                compare_lagrange(V, F, L, fid, uv, op, res)
            report(f"{mesh_name}, {label}", len(fid), res)
            del op


if __name__ == "__main__":
    main()
