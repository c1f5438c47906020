"""Benchmark static fitting (:func:`mi_loop.fitting.static.fit`): time per stage and accuracy.

Three parts, each printing Markdown tables:

``scan``
    The merged Stanford bunny range scan (118,245 oriented points) fitted with
    314 and 4667 control vertices: seconds per stage (min / median / max over
    ``--runs`` runs), iterations, and distances relative to the scan's bbox
    diagonal: ``p2s`` (scan points to the limit surface, exact point-triangle
    distances to a level-3 (314) or level-2 (4667) tessellation) and ``s2p``
    (100k area samples of the limit surface to the nearest scan point). Also:
    the template's own limit surface (before fitting), a screened Poisson
    depth-8 mesh of the same scan (pymeshlab, one thread, timed once in the
    same process), and one run each of the variants ``samples='level1'``,
    smaller IMLS radii ``--h0``, ARAP weight ``--alpha``, ``--tolerance`` and
    an iteration cap ``--iterations``.
``nps``
    Neural Parametric Surfaces protocol (P2S, HD x 1e-3, NAE degrees, extent 2,
    30k samples per side) on ``bunny.obj`` and ``fandisk.obj``: 100k area
    samples with face normals in, at most 1000 control vertices, level-3
    limit mesh against the target mesh.
``robust``
    ``bunny.obj`` samples with Gaussian noise (sigma 0.005 x largest extent on
    points, 0.01 on the unit normals), 5 % extra outliers uniform in the bbox
    with random normals, or a single-view partial scan (points with
    ``n . (view - p) > 0``, view 1 outside the bbox along +z at extent 2; no
    occlusion test); NPS metrics against the clean mesh and the ratio to the
    clean fit. Noise and outliers use alpha 0.1 (thesis, noisy data) and 0.01.

``cli``
    ``mi-loop fit SCAN --vertices 314`` and ``4667`` as a user runs them
    (``--runs`` times each, not part of ``all``): wall seconds from process
    start to exit (import, reading, template, fit, metrics, pictures, writing)
    and the fit's own total from ``report.json``.

Usage::

    cd <repository root>
    PYTHONPATH=. .venv/bin/python bench/bench_fit.py all            # 5-8 min on 2 cores
    PYTHONPATH=. .venv/bin/python bench/bench_fit.py scan --runs 3 --h0 0.005 0.0005
    PYTHONPATH=. .venv/bin/python bench/bench_fit.py nps
    PYTHONPATH=. .venv/bin/python bench/bench_fit.py robust
    PYTHONPATH=. .venv/bin/python bench/bench_fit.py cli --runs 3
    PYTHONPATH=. .venv/bin/python bench/bench_fit.py scan --quick   # timings: default fits only (~2 min)

``--json PATH`` also writes every row as JSON. Every table header repeats the
load average: other jobs on the machine inflate timings.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
SCAN = SHARED / "scans" / "bunny_rangescans_merged_stride3.ply"
STATIC = SHARED / "static"
NPS_TABLE1 = {"bunny": (1.347, 15.971, 5.39), "fandisk": (0.572, 8.743, 1.79)}  # P2S, HD (x1e-3), NAE (deg)
STAGES = ("template", "operator", "energies", "optimisation", "total")
SHORT = {"iterations": "max_it"}                   # fit() keyword -> table label
FIT_OPTIONS: dict = {}                                 # --cover: passed to every fit() call


# -- helpers -------------------------------------------------------------------
def load() -> str:
    return "load {:.2f} {:.2f} {:.2f}".format(*os.getloadavg())


def header() -> str:
    """Date, cores, commit, a hash of the package sources (the tree may be dirty) and the load."""
    try:
        commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                                capture_output=True, text=True).stdout.strip()
    except OSError:
        commit = "?"
    digest = hashlib.sha1(b"".join(p.read_bytes() for p in sorted((ROOT / "mi_loop").glob("*.py"))))
    return (f"{time.strftime('%Y-%m-%d %H:%M')}, nproc {os.cpu_count()}, commit {commit}, "
            f"mi_loop/*.py sha1 {digest.hexdigest()[:10]}, {load()}")


def table(title: str, columns, rows) -> None:
    print(f"\n### {title} ({load()})\n")
    print("| " + " | ".join(columns) + " |")
    print("|" + "---|" * len(columns))
    for r in rows:
        print("| " + " | ".join(r) + " |")


def limit_surface(V, F, level: int, cache: dict):
    """Limit points of a level-``level`` tessellation ``(V_lim, F_tess)``; the matrix is cached per ``F``."""
    from mi_loop.subdiv.limit import limit_matrix
    from mi_loop.subdiv.tessellation import tessellate

    key = (F.tobytes(), level)
    if key not in cache:
        fid, uv, F_t = tessellate(F, level)
        cache.clear()
        cache[key] = (limit_matrix(F, len(V), fid, uv), F_t)
    W, F_t = cache[key]
    return W @ V, F_t


def fit_summary(r) -> dict:
    """Iterations, energies and learning-rate decays of a :class:`FitResult`."""
    h = r.history
    lr = np.asarray(h["lr"])
    return {"iterations": len(h["total"]), "E0": h["total"][0], "E_best": min(h["total"]),
            "lr_changes": int((np.abs(np.diff(lr)) > 0).sum()), "h0": r.params["h0"],
            "n_samples": r.params["n_samples"], "n_vertices": r.params["n_vertices"]}


def f3(x):
    return f"{x:.3f}"


def pct(x):
    return f"{100 * x:.3f}"


def run_fits(P, N, runs: int, **kw):
    """``runs`` fits with the same arguments; returns (results, per-stage list of seconds)."""
    from mi_loop.fitting.options import FitOptions
    from mi_loop.fitting.static import fit

    results = [fit(P, N, FitOptions(**(FIT_OPTIONS | kw))) for _ in range(runs)]
    times = {s: [r.timings[s] for r in results] for s in STAGES}
    times["iterations"] = [len(r.history["total"]) for r in results]
    spread = max(float(np.abs(r.V - results[0].V).max()) for r in results)
    if spread > 0:
        print(f"  note: {kw}: control points differ across runs by up to {spread:.3g} "
              f"(iterations {times['iterations']})")
    return results, times


# -- scan ------------------------------------------------------------------------
def poisson_depth8(P, N):
    """Screened Poisson depth 8, one thread, as pymeshlab returns it; (V, F, seconds)."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=P, v_normals_matrix=N))
    t = time.perf_counter()
    ms.generate_surface_reconstruction_screened_poisson(depth=8, preclean=True, threads=1)
    sec = time.perf_counter() - t
    m = ms.current_mesh()
    return np.asarray(m.vertex_matrix(), np.float64), np.asarray(m.face_matrix(), np.int64), sec


def bench_scan(args, out: list) -> None:
    from mi_loop.io.points import load_oriented_points
    from mi_loop.metrics import two_sided

    P, N, _ = load_oriented_points(SCAN)
    sizes = [(314, 3), (4667, 2)]
    timing_rows, dist_rows, cache, poisson = [], [], {}, None

    def distances(label, V_lim, F_lim, extra=""):
        m = two_sided(V_lim, F_lim, P)
        row = {"case": label, **{k: m[k] for k in ("p2s_mean", "p2s_rms", "p2s_max",
                                                   "s2p_mean", "s2p_rms", "s2p_max")}}
        out.append({"part": "scan-distance", **row})
        dist_rows.append([label] + [pct(row[k]) for k in list(row)[1:]] + [extra])
        return m

    if not args.quick:
        Vp, Fp, sec = poisson_depth8(P, N)
        out.append({"part": "scan-poisson8", "seconds": sec, "vertices": len(Vp), "faces": len(Fp)})
        timing_rows.append(["Poisson depth 8 (1 thread)", "", "1", "", "", "", "", f"{sec:.2f}", "",
                            f"{len(Vp)} vertices"])
        poisson = distances("Poisson depth 8", Vp, Fp, f"{len(Vp)} vertices")

    configs = []                                 # (n, level, samples, {h0, alpha, tolerance}, runs)
    for n, level in sizes:                      # package defaults: level-1 samples, alpha 0.001
        configs.append((n, level, "level1", {}, args.runs))
        configs += [(n, level, "level1", {"tolerance": t}, 1) for t in args.tolerance if n == 4667]
        configs += [(n, level, "level1", {"iterations": k}, 1) for k in args.iterations]
        if args.quick:
            continue
        configs.append((n, level, "vertices", {}, 1))
        configs += [(n, level, "vertices", {"h0": h0}, 1) for h0 in args.h0 if n == 4667]
        configs += [(n, level, smp, {"alpha": a}, 1) for a in args.alpha for smp in ("vertices", "level1")]
    for n, level, samples, extra, runs in configs:
        results, times = run_fits(P, N, runs, n_vertices=n, samples=samples, **extra)
        r, s = results[-1], fit_summary(results[-1])
        label = f"{n} {samples}" + "".join(f" {SHORT.get(k, k)}={v:g}" for k, v in extra.items())
        med = {k: float(np.median(v)) for k, v in times.items()}
        out.append({"part": "scan-fit", "case": label, "runs": runs, "times": times, **s})
        timing_rows.append([label, str(s["n_samples"]), str(runs)] + [f3(med[k]) for k in STAGES[:-1]]
                           + [f"{min(times['total']):.2f} / {med['total']:.2f} / {max(times['total']):.2f}",
                              ", ".join(map(str, times["iterations"])),
                              f"{1e3 * med['optimisation'] / s['iterations']:.0f} ms/it, h0 {s['h0']:.4g}"])
        if samples == "level1" and not extra:
            V_lim, F_lim = limit_surface(r.V_template, r.F, level, cache)
            distances(f"{n} template (no fit), level {level}", V_lim, F_lim)
        V_lim, F_lim = limit_surface(r.V, r.F, level, cache)
        m = distances(f"{label}, level {level}", V_lim, F_lim, f"{s['iterations']} it")
        if n == 4667 and poisson is not None:
            ratio = m["p2s_mean"] / poisson["p2s_mean"]
            dist_rows[-1][-1] += f"; p2s mean = {ratio:.2f}x Poisson"
    table("Bunny scan: seconds per stage (median of runs; total min / median / max)",
          ["case", "samples", "runs", "template", "operator", "energies", "optimisation", "total",
           "iterations", "notes"], timing_rows)
    table("Bunny scan: distances, % of the scan's bbox diagonal (p2s: scan points to the surface; "
          "s2p: surface samples to the nearest scan point)",
          ["surface", "p2s mean", "p2s RMS", "p2s max", "s2p mean", "s2p RMS", "s2p max", "notes"], dist_rows)


# -- NPS protocol and robustness ---------------------------------------------------
def nps_row(label, V_lim, F_lim, target, ref=None):
    from mi_loop.metrics import nps_metrics

    m = nps_metrics((V_lim, F_lim), target)
    row = [label, f3(1e3 * m["P2S"]), f3(1e3 * m["HD"]), f"{m['NAE']:.2f}"]
    if ref is not None:
        row.append(f"{m['P2S'] / ref['P2S']:.2f} / {m['HD'] / ref['HD']:.2f} / {m['NAE'] / ref['NAE']:.2f}")
    return m, row


def fit_and_measure(P, N, target, cache, label, rows, out, ref=None, template_row=False, visible=False,
                    **kw):
    from mi_loop.fitting.options import FitOptions
    from mi_loop.fitting.static import fit

    mesh = kw.pop("mesh", None)
    r = fit(P, N, FitOptions(**({"n_vertices": 1000} | FIT_OPTIONS | kw)), mesh=mesh)
    s = fit_summary(r)
    note = (f"{s['n_vertices']} cv, {r.params.get('n_creases', 0)} crease edges, {s['iterations']} it, "
            f"{r.timings['total']:.1f} s, alpha {r.params['alpha']:g}, h0 {s['h0']:.4g}")
    if template_row:
        from mi_loop.subdiv.masks import limit_mesh

        V_lim, F_lim, _ = limit_mesh(r.V_template, r.F, 3, creases=r.creases)
        m0, row = nps_row(f"{label}: template (no fit)", V_lim, F_lim, target, ref)
        rows.append(row + ([""] if ref is None else []) + [""])
        out.append({"part": "nps", "case": f"{label} template", **m0})
    if r.creases is not None:                    # the cached operator has no creases
        V_lim, F_lim, _ = r.limit_mesh(3)
    else:
        V_lim, F_lim = limit_surface(r.V, r.F, 3, cache)
    m, row = nps_row(label, V_lim, F_lim, target, ref)
    if visible:                                  # input points to the fit, same units as P2S / HD
        from mi_loop.mesh.sampling import surface_distances

        d = surface_distances(V_lim, F_lim, P) * m["scale"]
        m |= {"input_to_fit_mean": float(d.mean()), "input_to_fit_max": float(d.max())}
        note += f"; input points to fit: mean {1e3 * d.mean():.3f}, max {1e3 * d.max():.3f}"
    rows.append(row + ([""] if ref is None else []) + [note])
    out.append({"part": "nps", "case": label, **m, **s, "timings": r.timings})
    return m


def bench_nps(args, out: list) -> None:
    from mi_loop.io import read_mesh
    from mi_loop.io.points import load_oriented_points

    rows, cache = [], {}
    for name, (p2s, hd, nae) in NPS_TABLE1.items():
        path = STATIC / f"{name}.obj"
        target = read_mesh(path)
        P, N, _ = load_oriented_points(path)
        rows.append([f"{name}: NPS Table 1", f3(p2s), f3(hd), f"{nae:.2f}", "", "published"])
        fit_and_measure(P, N, target, cache, f"{name}: mi_loop defaults (features from the mesh)", rows, out,
                        template_row=True, mesh=target)
        fit_and_measure(P, N, target, cache, f"{name}: --features off", rows, out, template_row=True,
                        mesh=target, features="off")
        for a in args.alpha:
            fit_and_measure(P, N, target, cache, f"{name}: level1, alpha {a:g}", rows, out,
                            samples="level1", alpha=a)
    table("NPS protocol (extent 2; P2S, HD x 1e-3; NAE degrees, unoriented)",
          ["surface", "P2S", "HD", "NAE", "", "notes"], rows)


def corrupt(P, N, kind: str, seed: int = 0):
    """Noise / outliers / single-view partial scan of oriented points (protocol in the module docstring)."""
    rng = np.random.default_rng(seed)
    lo, hi = P.min(0), P.max(0)
    centre, extent = (lo + hi) / 2, float((hi - lo).max())
    if kind == "noise":                          # sigma 0.01 at extent 2, on points and (unit) normals
        Pc = P + rng.normal(scale=0.005 * extent, size=P.shape)
        Nc = N + rng.normal(scale=0.01, size=N.shape)
        return Pc, Nc / np.linalg.norm(Nc, axis=1, keepdims=True)
    if kind == "outliers":                       # 5 % extra points uniform in the bbox, random normals
        k = int(round(0.05 * len(P)))
        Nr = rng.normal(size=(k, 3))
        return (np.vstack([P, lo + rng.random((k, 3)) * (hi - lo)]),
                np.vstack([N, Nr / np.linalg.norm(Nr, axis=1, keepdims=True)]))
    if kind == "partial":                        # viewpoint 1 (at extent 2) outside the bbox along +z
        Pn = (P - centre) * (2.0 / extent)
        view = np.array([0.0, 0.0, (hi[2] - centre[2]) * 2.0 / extent + 1.0])
        keep = np.einsum("ij,ij->i", N, view - Pn) > 0
        return P[keep], N[keep]
    raise ValueError(f"corrupt(): kind must be noise, outliers or partial, got {kind!r}")


def bench_robust(args, out: list) -> None:
    from mi_loop.io import read_mesh
    from mi_loop.io.points import load_oriented_points

    path = STATIC / "bunny.obj"
    target = read_mesh(path)
    P, N, _ = load_oriented_points(path)
    rows, cache = [], {}
    ref = fit_and_measure(P, N, target, cache, "clean, default alpha", rows, out)
    rows[-1][4] = "1.00 / 1.00 / 1.00"
    cases = [("noise", None), ("noise", 0.1), ("outliers", None), ("outliers", 0.1), ("partial", 0.01)]
    if not args.quick:
        cases += [("noise", 0.01), ("outliers", 0.01)]
    for kind, alpha in cases:
        Pc, Nc = corrupt(P, N, kind)
        how = "default alpha (noise-aware)" if alpha is None else f"alpha {alpha:g}"
        fit_and_measure(Pc, Nc, target, cache, f"{kind} ({len(Pc)} pts), {how}", rows, out,
                        ref=ref, alpha=alpha, visible=kind == "partial")
    table("Robustness, bunny.obj samples, 1000 control vertices, against the clean mesh "
          "(P2S, HD x 1e-3; NAE degrees; ratio to the clean fit)",
          ["input", "P2S", "HD", "NAE", "ratio P2S / HD / NAE", "notes"], rows)


def bench_cli(args, out):
    """``mi-loop fit SCAN --vertices N`` as a user runs it: wall seconds and the fit's own total."""
    import shutil
    import tempfile

    cli = ROOT / ".venv" / "bin" / "mi-loop"
    rows = []
    for n in (314, 4667):
        walls, fits = [], []
        for _ in range(args.runs):
            work = Path(tempfile.mkdtemp())
            t = time.perf_counter()
            subprocess.run([str(cli), "fit", str(SCAN), "-o", str(work / "out"), "--vertices", str(n), "--quiet"],
                           check=True, capture_output=True)
            walls.append(time.perf_counter() - t)
            fits.append(json.loads((work / "out" / "report.json").read_text())["timings_s"]["total"])
            shutil.rmtree(work)
        row = {"part": "cli", "vertices": n, "wall_s": walls, "fit_s": fits}
        out.append(row)
        rows.append([str(n), str(args.runs), f"{np.median(fits):.2f} ({min(fits):.2f}-{max(fits):.2f})",
                     f"{np.median(walls):.2f} ({min(walls):.2f}-{max(walls):.2f})"])
    table("mi-loop fit on the bunny scan, as a user runs it (seconds: median (min-max))",
          ["control vertices", "runs", "fit (report.json total)", "wall (process start to exit)"], rows)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("part", choices=("scan", "nps", "robust", "cli", "all"))
    ap.add_argument("--runs", type=int, default=3, help="runs of the default scan fits (median timings)")
    ap.add_argument("--h0", type=float, nargs="*", default=[0.005, 0.0005],
                    help="extra IMLS radii (unit box) tried at the largest scan size")
    ap.add_argument("--alpha", type=float, nargs="*", default=[0.001],
                    help="extra ARAP weights tried (scan: both sample modes; nps: level1)")
    ap.add_argument("--tolerance", type=float, nargs="*", default=[1e-3],
                    help="extra stopping tolerances tried at 4667 control vertices (default fit: 1e-4)")
    ap.add_argument("--iterations", type=int, nargs="*", default=[60],
                    help="extra iteration caps tried on the scan (default fit: 400, stops on its own)")
    ap.add_argument("--quick", action="store_true",
                    help="scan: default fits, --tolerance and --iterations rows only "
                         "(no Poisson depth 8, no other variants); "
                         "robust: no alpha 0.01 rows for noise and outliers")
    ap.add_argument("--cover", type=float, help="coverage weight of every fit (default: fit()'s)")
    ap.add_argument("--json", type=Path, help="also write all rows to this JSON file")
    args = ap.parse_args(argv)
    if args.cover is not None:
        FIT_OPTIONS["cover"] = args.cover

    import mi_loop

    mi_loop.set_variant("llvm_ad_rgb")
    print(header() + (f"\nfit() options: {FIT_OPTIONS}" if FIT_OPTIONS else ""))
    out, t0 = [], time.perf_counter()
    for part, fn in (("scan", bench_scan), ("nps", bench_nps), ("robust", bench_robust), ("cli", bench_cli)):
        if args.part == part or (args.part == "all" and part != "cli"):
            t = time.perf_counter()
            fn(args, out)
            print(f"\n({part}: {time.perf_counter() - t:.0f} s)")
    print(f"\n(total {time.perf_counter() - t0:.0f} s, {load()})")
    if args.json:
        args.json.write_text(json.dumps(out, indent=1, default=float))


if __name__ == "__main__":
    main()
