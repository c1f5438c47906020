"""Where the drift of a tracked D-FAUST fit comes from: the coarse stage alone, the graph's floor, the parts.

Reads a finished ``bench_dfaust.py complete`` run (``fit-sequence --track K``:
its ``state/NNNN.npz``, ``sequence.json``) and the points in correspondence
(``ref.npz``), and prints

1. **the coarse stage alone, frame by frame**: :func:`mi_loop.fitting.track.track`
   run from the run's own fit of frame ``t-1`` to frame ``t``'s points (normals
   estimated and oriented as ``fit-sequence`` does), and the drift of the tracked
   control points against the drift of that start and of the run's fit of frame
   ``t``: how much each frame's coarse stage adds, and how much the fine solve
   after it adds or removes;
2. **the graph's floor** (``--oracle``): the same graph driven by the true motion
   (each control vertex's limit point pulled onto where its attached material
   point went, point-to-point, frame after frame from frame 0). The drift left
   is what the graph cannot represent, plus the measure's own floor (frame 0).
   Then, frame by frame from the run's fit of ``t-1``: the true motion, the coarse
   stage, and the coarse stage started at the true motion (the graph's rest there
   too): the drift each adds, and the point-to-plane residual each leaves. Where
   the true motion leaves the larger residual, the data prefer the slide; where
   the stage started there stays there with a smaller residual than the stage from
   ``t-1``, the stage's rest (the previous fit) is what holds it off the true motion.
   The last column is the stage's own energy (its data term and its stiffness term at
   the last step) for the graph moved by the true motion and by the stage: where the
   true motion costs more, the stage's prior, not its optimisation, prefers the slide.
   ``--truth W`` is the weight pulling the graph onto the material points (1e4: onto
   each one, their noise too; 1: their smooth motion);
3. **the parts of the run's drift**, per frame: along the fit's normal and along
   the surface, and their mean vectors (a slide common to the whole body shows
   there);
4. **where** (``--where T``): the regions (cells of 20 cm) with the largest drift at
   frame ``T``, with the mean drift vector and the material's own motion since frame 0.

Drift is the metric of ``metrics.csv`` (:func:`mi_loop.metrics.drift`): each
control vertex's limit point at frame 0 tied to the triangle of its 3 nearest
reference points; mean distance to the same combination at frame ``t``,
percent of the frame-0 diagonal.

Usage::

    cd <repository root>
    PYTHONPATH=. .venv/bin/python bench/bench_dfaust.py complete --solvers adam --tag _t3 --extra="--track 10"
    PYTHONPATH=. .venv/bin/python bench/bench_track.py bench/results/dfaust/complete/adam_t3 --frames 1:17 \
        --oracle --where 16
    PYTHONPATH=. .venv/bin/python bench/bench_track.py RUN --frames 1:8 --stiff 10 10 --point 1   # a variant

Host NumPy/SciPy only; a frame's coarse stage takes 3-7 s on 2 cores.
"""
from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
REF = ROOT / "bench" / "results" / "dfaust" / "complete" / "ref.npz"


class Run:
    """A finished run: its states, unit box, and the attachment of its frame-0 fit to the reference."""

    def __init__(self, out: Path, ref: Path, spacing: int):
        from mi_loop.ad.operator import LimitOperator
        from mi_loop.fitting.static import sample_parameters
        from mi_loop.fitting.track import DeformationGraph
        from mi_loop.io.runs import read_state, state_path
        from mi_loop.metrics import attach_points
        from mi_loop.subdiv.masks import vertex_samples

        self.out, self.R = out, np.load(ref)["points"]
        meta = json.loads((out / "sequence.json").read_text())
        self.centre, self.scale = np.asarray(meta["centre"]), float(meta["scale"])
        self.states = [read_state(state_path(out, t)) for t in range(len(self.R)) if state_path(out, t).is_file()]
        first = self.states[0]
        self.F, n = first.F, len(first.x)
        fid, uv = sample_parameters(self.F, n, "level1", 0)             # fit-sequence's default samples
        self.matrices = LimitOperator(self.F, n, fid, uv, derivatives=True).matrix((None, "u", "v"))
        self.vertex = LimitOperator(self.F, n, *vertex_samples(self.F, n), derivatives=True).matrix((None, "u", "v"))
        self.graph = DeformationGraph(first.rest, self.F, spacing=spacing)
        self.diag = float(np.linalg.norm(np.ptp(self.R[0], axis=0)))
        self.attachment = attach_points(self.limit(first.x), self.R[0])
        self._frames = {}

    def limit(self, x):
        """Limit points of the control vertices of ``x`` (unit box), in the reference's units."""
        from mi_loop.subdiv.masks import limit_positions

        return limit_positions(np.asarray(x) * self.scale + self.centre, self.F)

    def drift(self, x, t: int):
        """``(k, 3)`` drift vectors of control points ``x`` at frame ``t``, percent of the diagonal."""
        return 100.0 * (self.limit(x) - self.attachment.points(self.R[t])) / self.diag

    def frame(self, t: int):
        """Frame ``t``'s points in the unit box and their normals, estimated and oriented by the run's fit of ``t-1``
        as ``fit-sequence`` does; computed once per frame."""
        from types import SimpleNamespace

        from mi_loop.app.sequence_frames import _orient
        from mi_loop.mesh.points import estimate_normals

        if t not in self._frames:
            P = (self.R[t] - self.centre) / self.scale
            self._frames[t] = P, _orient(SimpleNamespace(x=self.states[t - 1].x, F=self.F), P,
                                         estimate_normals(self.R[t]))
        return self._frames[t]


def mean_norm(d) -> float:
    return float(np.mean(np.linalg.norm(d, axis=1)))


def coarse(run: Run, frames, options: dict, predict: float = 0.0) -> None:
    from mi_loop.fitting.track import track

    label = ", ".join([f"{k} {v}" for k, v in options.items()] + ([f"predict {predict}"] if predict else []))
    print(f"\n### The coarse stage alone, from the run's fit of frame t-1 ({label or 'defaults'})\n")
    print("| frame | start drift % | tracked % | added by the stage | the run's fit % | added by the fine solve | s |")
    print("|---|---|---|---|---|---|---|")
    added = []
    for t in frames:
        x = run.states[t - 1].x
        P, N = run.frame(t)
        t0 = time.perf_counter()
        if predict and t >= 2:                # the control points' last motion once more: also the graph's rest
            x = x + predict * (x - run.states[t - 2].x)
        X, _ = track(run.graph, x, run.matrices, P, N, **options)
        seconds = time.perf_counter() - t0
        start, tracked = mean_norm(run.drift(run.states[t - 1].x, t - 1)), mean_norm(run.drift(X, t))
        fitted = mean_norm(run.drift(run.states[t].x, t)) if t < len(run.states) else float("nan")
        added.append(tracked - start)
        print(f"| {t} | {start:.3f} | {tracked:.3f} | {tracked - start:+.3f} | {fitted:.3f} | {fitted - tracked:+.3f} "
              f"| {seconds:.1f} |", flush=True)
    print(f"\nmean added by the stage per frame: {np.mean(added):+.4f} % ({os.cpu_count()} cores)")


def residual(run: Run, X, P, N, tree) -> float:
    """RMS point-to-plane distance (mm) of the correspondences the coarse stage keeps at control points ``X``."""
    from mi_loop.fitting.track import _correspondences

    Q, idx, ok = _correspondences(run.matrices, X, tree, N, 3.0)        # track()'s own rule (trim 3)
    k = np.flatnonzero(ok)
    return 1000.0 * run.scale * float(np.sqrt(np.mean(np.sum(N[idx[k]] * (Q[k] - P[idx[k]]), axis=1) ** 2)))


def energy(run: Run, V, X, info, P, N, tree, stiffness: float = 0.1, point: float = 0.1) -> tuple:
    """``(data, stiffness part)`` of :func:`~mi_loop.fitting.track.track`'s energy at its last step (stiffness 0.1),
    for the graph on control points ``V`` moved to ``X`` by ``info``'s node motions; correspondences found at ``X``."""
    from mi_loop.fitting.track import _correspondences, edge_residuals

    Q, idx, ok = _correspondences(run.matrices, X, tree, N, 3.0)
    k = np.flatnonzero(ok)
    r = Q[k] - P[idx[k]]
    data = float(np.mean(np.sum(N[idx[k]] * r, axis=1) ** 2 + point * np.sum(r * r, axis=1)))
    rr = edge_residuals(V[run.graph.nodes], run.graph.edges, info["R"], info["t"])[1]
    return data, stiffness * float(np.mean(np.sum(rr * rr, axis=1)))


def oracle(run: Run, frames, options: dict, truth: float = 1e4) -> None:
    """The graph driven by the true motion: control-vertex limit points pulled onto their material points with
    point-to-point weight ``truth`` (against stiffness 0.1: large, the graph follows every material point)."""
    from scipy.spatial import cKDTree

    from mi_loop.fitting.track import limit_samples, track
    from mi_loop.metrics import attach_points

    def driven(x, t, attachment, info=False):
        target = (attachment.points(run.R[t]) - run.centre) / run.scale
        result = track(run.graph, x, run.vertex, target, limit_samples(run.vertex, x)[1], point=truth, trim=1e9,
                       stiff=(0.1, 0.1))
        return result if info else result[0]

    print("\n### The graph's floor: driven by the true motion from frame 0\n")
    x = run.states[0].x
    cells = [f"0: {mean_norm(run.drift(x, 0)):.3f}"]
    for t in range(1, max(frames) + 1):
        x = driven(x, t, run.attachment)
        cells.append(f"{t}: {mean_norm(run.drift(x, t)):.3f}")
    print("drift mean %, frame: " + ", ".join(cells))
    print("\n### From the run's fit of frame t-1: the true motion against the coarse stage\n")
    print("| frame | drift added: true motion / stage / stage started at the true motion | "
          "residual mm: the same three / start | stage energy x 1e6, data + stiffness: true motion / stage |")
    print("|---|---|---|---|")
    for t in frames:
        x = run.states[t - 1].x
        P, N = run.frame(t)
        tree = cKDTree(P)
        start = mean_norm(run.drift(x, t - 1))
        true, true_info = driven(x, t, attach_points(run.limit(x), run.R[t - 1]), info=True)   # own material points
        stage, stage_info = track(run.graph, x, run.matrices, P, N, tree, **options)
        three = [true, stage, track(run.graph, true, run.matrices, P, N, tree, **options)[0]]
        added = " / ".join(f"{mean_norm(run.drift(y, t)) - start:+.3f}" for y in three)
        left = " / ".join(f"{residual(run, y, P, N, tree):.3f}" for y in three + [x])
        kw = {k: options[k] for k in ("point",) if k in options}
        if "stiff" in options:
            kw["stiffness"] = options["stiff"][1]
        energies = " / ".join("{:.3f} + {:.3f}".format(*(1e6 * e for e in energy(run, x, y, i, P, N, tree, **kw)))
                              for y, i in ((true, true_info), (stage, stage_info)))
        print(f"| {t} | {added} | {left} | {energies} |", flush=True)


def parts(run: Run) -> None:
    from mi_loop.mesh.geometry import vertex_normals

    print("\n### The run's drift along the normal and along the surface\n")
    print("| frame | drift mean % | along the normal | along the surface | mean vector along the surface (x, y, z) |")
    print("|---|---|---|---|---|")
    for t, state in enumerate(run.states):
        d = run.drift(state.x, t)
        n = vertex_normals(run.limit(state.x), run.F)
        along = np.sum(d * n, axis=1)
        tangent = d - along[:, None] * n
        vector = ", ".join(f"{v:+.3f}" for v in tangent.mean(axis=0))
        print(f"| {t} | {mean_norm(d):.3f} | {np.mean(np.abs(along)):.3f} | {mean_norm(tangent):.3f} | {vector} |")


def where(run: Run, t: int, cell: float = 0.2, rows: int = 12) -> None:
    print(f"\n### Where the drift is at frame {t} (cells of {cell} in the reference's units)\n")
    print("| cell centre (x, y, z) | vertices | drift mean % | mean drift vector % | "
          "material's motion since frame 0 % |")
    print("|---|---|---|---|---|")
    L0 = run.limit(run.states[0].x)
    d = run.drift(run.states[t].x, t)
    motion = 100.0 * (run.attachment.points(run.R[t]) - run.attachment.points(run.R[0])) / run.diag
    key = np.floor((L0 - run.R[0].min(axis=0)) / cell).astype(np.int64)
    _, inverse = np.unique(key, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    found = []
    for c in range(inverse.max() + 1):
        m = inverse == c
        if m.sum() >= 5:
            found.append((mean_norm(d[m]), int(m.sum()), L0[m].mean(0), d[m].mean(0), motion[m].mean(0)))
    def fmt(v, p):
        return "(" + ", ".join(f"{a:+.{p}f}" for a in v) + ")"

    for size, count, centre, vector, moved in sorted(found, key=lambda r: -r[0])[:rows]:
        print(f"| {fmt(centre, 2)} | {count} | {size:.2f} | {fmt(vector, 2)} | {fmt(moved, 2)} |")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run", type=Path, help="a finished bench_dfaust.py complete run (fit-sequence OUTDIR)")
    ap.add_argument("--ref", type=Path, default=REF, help="the points in correspondence (bench_dfaust.py's ref.npz)")
    ap.add_argument("--frames", default="1:8", help="START:STOP of the frames whose coarse stage is run")
    ap.add_argument("--spacing", type=int, default=10, help="about one graph node per SPACING control points "
                    "(fit-sequence --track)")
    ap.add_argument("--stiff", type=float, nargs=2, default=None, help="track()'s stiffness, first and last step")
    ap.add_argument("--point", type=float, default=None, help="track()'s point-to-point weight")
    ap.add_argument("--steps", type=int, default=None, help="track()'s Gauss-Newton steps")
    ap.add_argument("--predict", type=float, default=0.0, help="start each frame's stage (and put the graph's rest) "
                    "at x_(t-1) + PREDICT (x_(t-1) - x_(t-2)), the run's fits")
    ap.add_argument("--oracle", action="store_true", help="also the graph driven by the true motion")
    ap.add_argument("--truth", type=float, default=1e4, help="with --oracle: the weight that pulls the graph onto "
                    "the material points (default %(default)s: it follows them all, their noise too)")
    ap.add_argument("--where", type=int, default=None, help="the regions of largest drift at this frame")
    args = ap.parse_args()
    run = Run(args.run, args.ref, args.spacing)
    start, stop = (int(v) for v in args.frames.split(":"))
    frames = range(max(start, 1), min(stop, len(run.states)))
    options = {k: v for k, v in (("stiff", tuple(args.stiff) if args.stiff else None), ("point", args.point),
                                 ("steps", args.steps)) if v is not None}
    coarse(run, frames, options, args.predict)
    if args.oracle:
        oracle(run, frames, {}, args.truth)
    parts(run)
    if args.where is not None:
        where(run, args.where)


if __name__ == "__main__":
    main()
