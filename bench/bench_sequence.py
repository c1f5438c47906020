"""Benchmark spatio-temporal fitting (``mi-loop fit-sequence``): accuracy per frame and cost.

Two parts, each printing Markdown tables:

``fit``
    A simulated capture of each sequence: every frame of the NPZ is re-sampled
    independently (random edge splits and 1-to-3 face splits with a per-frame
    seed, so the connectivity changes from frame to frame while the surface
    stays exactly the same; the distance moved is printed) and written as a
    directory of PLY files. ``mi-loop fit-sequence`` then fits it with three
    configurations: IMLS only (``--no-image``), IMLS + image (default) and
    image only (``--image-only``). The mean / RMS two-sided distance of every
    frame's limit surface (``limit/NNNN.ply``) to the CLEAN frame (the NPZ
    mesh, not the re-sampled one) is computed with
    :func:`mi_loop.metrics.two_sided`, relative to the frame's bbox diagonal.
``cost``
    One iteration of the geometric part (limit operator + IMLS + coverage +
    ARAP + backward, level-1 samples) against one render + backward of the
    limit mesh (one view, the default resolution and spp), on the spot
    template; then the per-frame work outside the iterations (target renders,
    IMLS set-up, output mesh, metrics).
``folds``
    Share of each frame's limit surface (of finished ``fit`` runs) whose
    normal points against the nearest target face's: folds where the surface
    turned over on itself.

Usage::

    cd <repository root>
    PYTHONPATH=. .venv/bin/python bench/bench_sequence.py fit            # both sequences, 3 configs
    PYTHONPATH=. .venv/bin/python bench/bench_sequence.py fit --seq spot --frames 4 --configs image \\
        --extra="--beta 4"                                               # a settings sweep point
    PYTHONPATH=. .venv/bin/python bench/bench_sequence.py cost
    PYTHONPATH=. .venv/bin/python bench/bench_sequence.py folds --tag _defaults

Runs go to ``bench/results/sequence/`` (not tracked). Every table repeats the
load average: other jobs on the machine inflate timings.
"""
from __future__ import annotations

import argparse
import os
import shlex
import subprocess
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SEQ = Path(__file__).resolve().parents[2] / "shared" / "data" / "sequences"
RESULTS = ROOT / "bench" / "results" / "sequence"
SEQUENCES = {"spot": ("spot_arap_16f.npz", 1000), "fox": ("fox_walk_24f.npz", 1000)}
CONFIGS = {"imls": ["--no-image"], "image": [], "dr": ["--image-only"]}
LABELS = {"imls": "IMLS only", "image": "IMLS + image", "dr": "image only"}


def load() -> str:
    return "load {:.2f} {:.2f} {:.2f}".format(*os.getloadavg())


# -- simulated capture -----------------------------------------------------------
def resample(V, F, seed: int, edge_fraction: float = 0.4, face_fraction: float = 0.3):
    """Re-sample a mesh without moving its surface: random edge splits, then 1-to-3 face splits.

    Edges are split at a random point (t in [0.25, 0.75]); the chosen edges share
    no face, so each split turns the two faces of the edge into four. Then a
    random subset of faces is split at a random interior point. Returns ``(V, F)``.
    """
    rng = np.random.default_rng(seed)
    E = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    edges, inverse = np.unique(E, axis=0, return_inverse=True)
    face_of = np.tile(np.arange(len(F)), 3)
    used = np.zeros(len(F), bool)
    chosen = []
    for e in rng.permutation(len(edges))[: int(edge_fraction * len(edges) * 2)]:
        faces = face_of[inverse.ravel() == e]
        if len(faces) == 2 and not used[faces].any():
            used[faces] = True
            chosen.append(e)
        if len(chosen) >= edge_fraction * len(edges) / 3:
            break
    chosen = np.array(chosen)
    t = rng.uniform(0.25, 0.75, len(chosen))[:, None]
    a, b = edges[chosen, 0], edges[chosen, 1]
    mid = len(V) + np.arange(len(chosen))
    V = np.concatenate([V, (1 - t) * V[a] + t * V[b]])
    lookup = {(int(x), int(y)): int(m) for x, y, m in zip(a, b, mid)}
    out = []
    for f in F:
        for k in range(3):
            i, j, o = int(f[k]), int(f[(k + 1) % 3]), int(f[(k + 2) % 3])
            m = lookup.get((min(i, j), max(i, j)))
            if m is not None:
                out += [(i, m, o), (m, j, o)]
                break
        else:
            out.append(tuple(int(v) for v in f))
    F = np.array(out)
    pick = rng.random(len(F)) < face_fraction
    w = rng.dirichlet([4.0, 4.0, 4.0], pick.sum())
    c = len(V) + np.arange(pick.sum())
    V = np.concatenate([V, np.einsum("fk,fkd->fd", w, V[F[pick]])])
    Fp = F[pick]
    split = np.concatenate([np.c_[Fp[:, 0], Fp[:, 1], c], np.c_[Fp[:, 1], Fp[:, 2], c], np.c_[Fp[:, 2], Fp[:, 0], c]])
    return V, np.concatenate([F[~pick], split])


def prepare(name: str, n_frames: int | None):
    """Write the re-sampled frames of a sequence as PLY files; returns (dir, clean frames, movement)."""
    from mi_loop import io, metrics

    data = np.load(SEQ / SEQUENCES[name][0])
    Vs, F = np.asarray(data["vertices"], np.float64), np.asarray(data["faces"])
    if n_frames:
        Vs = Vs[:n_frames]
    frames = io.ensure_writable_dir(RESULTS / name / f"frames_{len(Vs)}")
    moved, sizes = [], []
    for t, V in enumerate(Vs):
        Vr, Fr = resample(V, F, seed=1000 + t)
        io.write_ply(frames / f"{t:04d}.ply", Vr, Fr)
        if t in (0, len(Vs) - 1):
            d = metrics.two_sided(Vr, Fr, V, F, n_samples=30_000)
            moved.append(max(d["hausdorff"], d["mean"]))
        sizes.append(len(Vr))
    print(f"{name}: {len(Vs)} frames, clean {len(Vs[0])} vertices, re-sampled {min(sizes)}-{max(sizes)} "
          f"vertices; max two-sided distance re-sampled vs clean (first/last frame) {max(moved):.1e}")
    return frames, (Vs, F)


# -- fitting runs ----------------------------------------------------------------
def run(name, config, frames, extra, tag):
    """Run ``mi-loop fit-sequence``; returns (outdir, wall seconds)."""
    out = RESULTS / name / f"{config}{tag}"
    vertices = SEQUENCES[name][1]
    cmd = [str(ROOT / ".venv" / "bin" / "mi-loop"), "fit-sequence", str(frames), "-o", str(out),
           "--vertices", str(vertices), *CONFIGS[config], *extra]
    print(f"$ {' '.join(shlex.quote(c) for c in cmd)}   [{load()}]", flush=True)
    t = time.perf_counter()
    subprocess.run(cmd, check=True, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return out, time.perf_counter() - t


def clean_errors(out, clean):
    """Per-frame mean / RMS two-sided distance of limit/NNNN.ply to the clean frames, plus seconds."""
    from mi_loop import io, metrics

    Vs, F = clean
    import csv

    with open(out / "metrics.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    res = []
    for r in rows:
        t = int(r["frame"])
        V_lim, F_lim = io.read_mesh(out / "limit" / f"{t:04d}.ply")
        d = metrics.two_sided(V_lim, F_lim, Vs[t], F, n_samples=30_000)
        res.append((t, d["mean"], d["rms"], float(r["seconds"]), float(r["time_render"])))
    return np.array(res)


def fit_part(args):
    extra = shlex.split(args.extra)
    tag = args.tag or ("_" + "_".join(e.lstrip("-") for e in extra) if extra else "")
    for name in args.seq:
        frames, clean = prepare(name, args.frames)
        summary = []
        for config in args.configs:
            out, wall = run(name, config, frames, extra, tag + (f"_{args.frames}f" if args.frames else ""))
            res = clean_errors(out, clean)
            np.savetxt(out / "clean_errors.csv", res, delimiter=",", fmt="%.6g",
                       header="frame,mean,rms,seconds,time_render", comments="")
            summary.append((config, res, wall, load()))
            print(f"  {LABELS[config]}: per frame mean " + " ".join(f"{m:.5f}" for m in res[:, 1]))
            print(f"  {LABELS[config]}: per frame RMS  " + " ".join(f"{m:.5f}" for m in res[:, 2]))
        print(f"\n{name}, {len(clean[0])} frames, extra options {extra or 'none'}\n")
        print("| config | last mean | last RMS | max mean | max RMS | frames with mean<=0.001 & RMS<=0.002 "
              "| s/frame (median, frames 1..) | render s/frame | wall s | load after |")
        print("|---|---|---|---|---|---|---|---|---|---|")
        for config, res, wall, ld in summary:
            ok = int(((res[:, 1] <= 1e-3) & (res[:, 2] <= 2e-3)).sum())
            sec = res[1:, 3] if len(res) > 1 else res[:, 3]
            print(f"| {LABELS[config]} | {res[-1, 1]:.6f} | {res[-1, 2]:.6f} | {res[:, 1].max():.6f} | "
                  f"{res[:, 2].max():.6f} | {ok}/{len(res)} | {np.median(sec):.2f} | {np.median(res[:, 4]):.2f} "
                  f"| {wall:.0f} | {ld.split(' ', 1)[1]} |")
        print(flush=True)


# -- cost of one iteration -----------------------------------------------------------
def cost_part(args):
    import drjit as dr
    import mitsuba as mi

    from mi_loop.ad.operator import LimitOperator
    from mi_loop.energies.arap import ARAP
    from mi_loop.energies.coverage import Coverage
    from mi_loop.energies.imls import IMLS
    from mi_loop.fitting.sequence import Rig, SequenceOptions
    from mi_loop.fitting.static import Normalisation, sample_parameters
    from mi_loop.fitting.template import mesh_template
    from mi_loop.mesh.sampling import sample_surface
    from mi_loop.render.variant import set_variant

    set_variant("llvm_ad_rgb")
    data = np.load(SEQ / SEQUENCES["spot"][0])
    V, F_t = np.asarray(data["vertices"][0], np.float64), np.asarray(data["faces"])
    P, N, _ = sample_surface(V, F_t, 20_000, seed=0)
    norm = Normalisation.of(P)
    x0, F, _ = mesh_template(norm.forward(V), F_t, 1000)
    options = SequenceOptions()
    fid, uv = sample_parameters(F, len(x0), "level1")       # the CLI's default --samples
    op = LimitOperator(F, len(x0), fid, uv, derivatives=False)
    imls = IMLS(norm.forward(P), N)
    cover = Coverage(norm.forward(P), N, tree=imls.tree)
    arap = ARAP(x0, F)
    lo, hi = x0.min(0), x0.max(0)
    pad = 0.15 * (hi - lo).max()
    rig = Rig(options, (lo - pad, hi + pad))
    Vn = norm.forward(V)
    renderer = rig.images(x0, F, (Vn, F_t), 0).renderer()
    alpha = dr.opaque(mi.Float, options.alpha / len(x0))
    base = x0.ravel().astype(np.float32)
    Q = np.array(op.positions(mi.Float(base)), dtype=np.float64).T
    imls.update(Q)
    cover.update(Q)

    def geometric(i):
        x = mi.Float(base + 1e-4 * i)
        dr.enable_grad(x)
        R = arap.rotations(np.array(x, dtype=np.float64).reshape(-1, 3))
        Q = op.positions(x)
        E = (imls.energy(Q, reduce="mean") + options.cover_weight(mesh_frame=True) * cover.energy(Q)
             + alpha * arap.energy(x, R))
        dr.backward(E)
        dr.eval(dr.grad(x))

    def image(i):
        x = mi.Float(base + 1e-4 * i)
        dr.enable_grad(x)
        renderer.backward(x, None, [i % options.views], seed=i)     # render + its reverse pass
        dr.eval(dr.grad(x))

    def timed(f, n):
        for i in range(3):
            f(i)
        dr.sync_thread()
        ts = []
        for i in range(n):
            t = time.perf_counter()
            f(i + 3)
            dr.sync_thread()
            ts.append(time.perf_counter() - t)
        return np.array(ts) * 1e3

    def refresh(i):      # neighbour lists, as fit_frame does every 10 iterations
        Qi = np.array(op.positions(mi.Float(base + 1e-4 * i)), dtype=np.float64).T
        imls.update(Qi)
        cover.update(Qi)

    g = timed(geometric, args.runs)
    u = timed(refresh, args.runs)
    r = timed(image, args.runs)
    once = per_frame_costs(V, F_t, x0, F, norm, rig)
    print(f"\nCost per iteration, spot template {len(x0)} control vertices ({len(F)} faces, "
          f"{len(fid)} limit samples), "
          f"render {options.resolution}^2 at {options.spp} spp, level {options.level}, one view [{load()}]\n")
    print("| step | min ms | median ms | max ms |")
    print("|---|---|---|---|")
    for label, a in (("limit operator + IMLS + coverage + ARAP (+ rotations) + backward", g),
                     ("IMLS + coverage neighbour refresh (every 10 iterations)", u),
                     ("one render + backward (direct_projective, 1 view)", r)):
        print(f"| {label} | {a.min():.1f} | {np.median(a):.1f} | {a.max():.1f} |")
    geo = np.median(g) + np.median(u) / 10
    print(f"\nratio geometric (refresh amortised over 10 iterations) / render (medians): "
          f"{geo / np.median(r):.1%}; per iteration with 2 views: {geo / (2 * np.median(r)):.1%}")
    print("\nPer-frame work outside the iterations (one run each):\n")
    print("| step | s |")
    print("|---|---|")
    for label, s in once.items():
        print(f"| {label} | {s:.2f} |")


def per_frame_costs(V, F_t, x0, F, norm, rig):
    """Seconds of the per-frame steps of ``mi-loop fit-sequence`` that are not iterations."""
    from mi_loop.energies.coverage import Coverage
    from mi_loop.energies.imls import IMLS
    from mi_loop.mesh.sampling import sample_surface
    from mi_loop.metrics import two_sided
    from mi_loop.subdiv.masks import limit_mesh

    out, t = {}, time.perf_counter()

    def lap(label):
        nonlocal t
        out[label] = time.perf_counter() - t
        t = time.perf_counter()

    P, N, _ = sample_surface(V, F_t, 20_000, seed=1)
    lap("sample 20k oriented points on the frame")
    Pn = norm.forward(P)
    Coverage(Pn, N, tree=IMLS(Pn, N).tree)
    lap("IMLS + coverage set-up (20k points)")
    Vn = norm.forward(V)
    rig.images(x0, F, (Vn, F_t), 1).renderer()
    lap(f"target renders ({len(rig.cameras)} views, {rig.options.target_spp} spp)")
    limit = limit_mesh(norm.inverse(x0), F, level=2)
    lap("limit mesh for output (level 2, P + du + dv rows, SciPy)")
    two_sided(limit[0], limit[1], V, F_t, n_samples=30_000)        # as fit-sequence's per-frame metrics
    lap("metrics.csv distances (two_sided, 30k samples per side)")
    return out


# -- folds: area of the limit surface facing the wrong way ------------------------
def flipped_fraction(V_lim, F_lim, V, F) -> float:
    """Share of the limit surface's area whose normal points against the nearest target face's
    (:func:`mi_loop.metrics.flipped_fraction`, which ``fit-sequence`` now writes to ``metrics.csv``)."""
    from mi_loop.metrics import flipped_fraction as flipped

    return flipped(V_lim, F_lim, V, F)


def folds_part(args):
    """Flipped area (% of the limit surface) per frame of finished ``fit`` runs."""
    from mi_loop import io

    print(f"\nFlipped area, % of the limit surface (runs tagged '{args.tag}') [{load()}]\n")
    print("| sequence | config | frame 0 | middle frame | last frame | largest (frame) |")
    print("|---|---|---|---|---|---|")
    for name in args.seq:
        data = np.load(SEQ / SEQUENCES[name][0])
        Vs, F = np.asarray(data["vertices"], np.float64), np.asarray(data["faces"])
        for config in args.configs:
            out = RESULTS / name / f"{config}{args.tag}"
            if not (out / "limit").is_dir():
                continue
            pct = [100 * flipped_fraction(*io.read_mesh(out / "limit" / f"{t:04d}.ply"), Vs[t], F)
                   for t in range(len(Vs))]
            worst = int(np.argmax(pct))
            print(f"| {name} | {LABELS[config]} | {pct[0]:.2f} | {pct[len(pct) // 2]:.2f} | {pct[-1]:.2f} | "
                  f"{pct[worst]:.2f} ({worst}) |", flush=True)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="part", required=True)
    fit = sub.add_parser("fit")
    fit.add_argument("--seq", nargs="+", choices=sorted(SEQUENCES), default=["spot", "fox"])
    fit.add_argument("--configs", nargs="+", choices=list(CONFIGS), default=list(CONFIGS))
    fit.add_argument("--frames", type=int, help="first N frames only (settings sweeps)")
    fit.add_argument("--extra", default="", help="extra fit-sequence options, e.g. '--beta 4'")
    fit.add_argument("--tag", default="", help="suffix of the output directory")
    cost = sub.add_parser("cost")
    cost.add_argument("--runs", type=int, default=20)
    folds = sub.add_parser("folds")
    folds.add_argument("--seq", nargs="+", choices=sorted(SEQUENCES), default=["spot", "fox"])
    folds.add_argument("--configs", nargs="+", choices=list(CONFIGS), default=list(CONFIGS))
    folds.add_argument("--tag", default="_defaults", help="suffix of the runs' output directories")
    args = parser.parse_args()
    print(f"# {time.strftime('%Y-%m-%d %H:%M:%S %Z')}, nproc {os.cpu_count()}, {load()}")
    {"fit": fit_part, "cost": cost_part, "folds": folds_part}[args.part](args)


if __name__ == "__main__":
    main()
