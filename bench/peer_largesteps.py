"""The peer of ``mi-loop fit-images``: Mitsuba's shape-optimisation tutorial pipeline, under a wall-time budget.

Mitsuba's ``inverse_rendering/shape_optimization.ipynb`` (mitsuba-tutorials) fits a triangle
mesh to multi-view photos: an icosphere's vertex positions are optimised through
``mi.ad.LargeSteps`` (the latent ``u = (I + lambda L) v`` of Nicolet et al. 2021, solved with
``cholespy``), Adam with ``uniform=True``, one view (render + L1 image loss + backward) per
step, ``direct_projective`` with ``sppi: 0``, and one Botsch-Kobbelt remesh half-way
(``gpytoolbox.remesh_botsch(v, f, i=5, h=mean_edge / 2, project=True)``) after which the
latent variable and the optimiser are rebuilt. :func:`fit_largesteps` runs that pipeline on
given sensors and target images until a wall-clock budget is spent, the remesh (and an
optional coarse-to-fine resolution schedule) placed at fractions of that budget.

What differs from the notebook (each also recorded in the returned ``settings``):

- a time budget instead of 2 x 100 epochs; the remesh at a fraction of the budget;
- ``spp`` for the differentiable renders is a setting (the notebook renders with the
  sensors' 128 spp, far too slow on two CPU cores);
- after the remesh the notebook accumulates the gradients of all its 8 views into one step
  and turns indirect-visibility gradients on (``sppi`` at its default); here both are
  settings (``views_per_step_after``, ``sppi_after``), defaults from the tuning below;
- ``lr`` is relative to the bounding-box diagonal of ``bbox`` (the notebook's lr 0.1 on
  Suzanne, diagonal 4.6, is lr 0.022 here);
- the initial sphere is centred in ``bbox`` with radius half its smallest side (the notebook's
  unit sphere against Suzanne, smallest side 1.97, is the same ratio), an icosphere from
  ``trimesh`` (subdivision 5 has the notebook's ``ico_10k.ply`` connectivity: 10,242
  vertices, 20,480 faces, without its UV-seam duplicates);
- optional per-vertex albedo (``albedo=None``): a ``mesh_attribute`` ``vertex_color``
  reflectance optimised with a plain Adam and clamped to [0, 1]; the notebook knows the
  material. Colours are carried over a remesh by barycentric interpolation at the closest
  point of the old mesh;
- the remesher: ``gpytoolbox.remesh_botsch`` as in the notebook when ``gpytoolbox`` is
  importable, otherwise pymeshlab's ``meshing_isotropic_explicit_remeshing`` (the same
  split / collapse / flip / tangential-relaxation scheme, with reprojection) at the same
  target edge length.

Usage as a script (tuning on a real target, see ``--help``)::

    .venv/bin/python bench/peer_largesteps.py ../shared/data/multiview/bunny.obj --budget 120 \
        --json bench/results/peer_tuning.jsonl
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

import mi_loop  # before anything imports Dr.Jit: picks a libLLVM >= 16

__all__ = ["CONSTANT_EMITTER", "fibonacci_sensors", "fit_largesteps", "image_l1", "load_target",
           "normalise", "render_targets"]

#: The capture lighting of the benchmark: a uniform white environment.
CONSTANT_EMITTER = {"type": "constant", "radiance": {"type": "rgb", "value": 1.0}}

_INSTALL = "pip install cholespy  (or pip install -e '.[bench]')"


def _mitsuba():
    import mitsuba as mi

    if not mi.variant():
        mi_loop.set_variant("llvm_ad_rgb")
    return mi


def _require_cholespy():
    try:
        import cholespy  # noqa: F401
    except ImportError as exc:   # LargeSteps imports it lazily, deep inside the first step
        raise ImportError(f"fit_largesteps needs cholespy for mi.ad.LargeSteps: {_INSTALL}") from exc


# --------------------------------------------------------------------------- scene pieces

def _sensor(desc: dict, width: int | None, spp: int, sample_border: bool = True):
    """Load a perspective sensor dict with an RGB film of ``width`` (height in proportion)."""
    mi = _mitsuba()
    desc = dict(desc)
    film = dict(desc.get("film", {"type": "hdrfilm"}))
    W, H = int(film.get("width", 256)), int(film.get("height", 256))
    if width is not None and width != W:
        film["height"] = max(1, round(H * width / W))
        film["width"] = int(width)
    film["pixel_format"] = "rgb"
    film["sample_border"] = sample_border          # the notebook's setting: objects may cross the border
    desc["film"] = film
    desc["sampler"] = {"type": "independent", "sample_count": int(spp)}
    return mi.load_dict(desc)


def _downsample(img: np.ndarray, h: int, w: int) -> np.ndarray:
    """Box-average ``img`` (H, W, C) to (h, w, C); integer factors exactly, others by area weights."""
    H, W = img.shape[:2]
    if (H, W) == (h, w):
        return img
    if H % h == 0 and W % w == 0:
        return img.reshape(h, H // h, w, W // w, -1).mean(axis=(1, 3))

    def weights(n_in, n_out):
        edges = np.linspace(0, n_in, n_out + 1)
        A = np.zeros((n_out, n_in))
        for i in range(n_out):
            lo, hi = edges[i], edges[i + 1]
            for j in range(int(lo), min(n_in, math.ceil(hi))):
                A[i, j] = min(hi, j + 1) - max(lo, j)
        return A / A.sum(1, keepdims=True)

    return np.einsum("ij,jkc,lk->ilc", weights(H, h), img, weights(W, w))


def _mesh(V, F, colors=None, albedo=0.5):
    """A Mitsuba mesh with smooth (recomputed) vertex normals and a diffuse BSDF."""
    mi = _mitsuba()
    props = mi.Properties()
    if colors is None:
        props["bsdf"] = mi.load_dict({"type": "diffuse", "reflectance": {"type": "rgb", "value": float(albedo)}})
    else:
        props["bsdf"] = mi.load_dict({"type": "diffuse",
                                      "reflectance": {"type": "mesh_attribute", "name": "vertex_color"}})
    mesh = mi.Mesh("shape", len(V), len(F), props, has_vertex_normals=True)
    if colors is not None:
        mesh.add_attribute("vertex_color", 3, mi.Float(np.asarray(colors, np.float32).ravel()))
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(np.asarray(V, np.float32).ravel())
    params["faces"] = mi.UInt32(np.asarray(F, np.uint32).ravel())
    params.update()                                # vertex normals recomputed (smooth shading)
    return mesh


def _scene(mesh, emitter, integrator):
    mi = _mitsuba()
    return mi.load_dict({"type": "scene", "integrator": integrator, "emitter": dict(emitter), "shape": mesh})


def _key(params, suffix):
    return next(k for k in params.keys() if k.endswith(suffix))


def _icosphere(subdivisions, centre, radius):
    import trimesh

    ico = trimesh.creation.icosphere(subdivisions=int(subdivisions), radius=1.0)
    return np.asarray(ico.vertices) * radius + np.asarray(centre), np.asarray(ico.faces, dtype=np.int64)


def _mean_edge(V, F):
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    return float(np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1).mean())


def _remesh(V, F, h, remesher):
    """Remesh to target edge length ``h``; returns (V, F, name of the remesher used)."""
    if remesher in ("auto", "botsch"):
        try:
            from gpytoolbox import remesh_botsch
        except ImportError:
            if remesher == "botsch":
                raise
        else:   # the notebook's call: 5 iterations, project onto the input surface
            V2, F2 = remesh_botsch(np.asarray(V, np.float64), np.asarray(F, np.int32), i=5, h=h, project=True)
            return np.asarray(V2, np.float64), np.asarray(F2, np.int64), "gpytoolbox.remesh_botsch(i=5, project)"
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(np.asarray(V, np.float64), np.asarray(F, np.int32)))
    ms.meshing_isotropic_explicit_remeshing(iterations=5, targetlen=pymeshlab.PureValue(h), reprojectflag=True)
    m = ms.current_mesh()
    return (np.asarray(m.vertex_matrix(), np.float64), np.asarray(m.face_matrix(), np.int64),
            "pymeshlab.meshing_isotropic_explicit_remeshing(iterations=5, reproject)")


def _transfer_colors(V_old, F_old, C_old, V_new):
    """Per-vertex colours at the closest points of the old mesh (barycentric interpolation)."""
    from mi_loop.mesh.sampling import closest_points

    _, P, face = closest_points(V_old, F_old, V_new)
    a, b, c = (V_old[F_old[face, i]] for i in range(3))
    v0, v1, v2 = b - a, c - a, P - a
    d00, d01, d11 = (v0 * v0).sum(1), (v0 * v1).sum(1), (v1 * v1).sum(1)
    d20, d21 = (v2 * v0).sum(1), (v2 * v1).sum(1)
    den = np.where(np.abs(d00 * d11 - d01 ** 2) > 1e-30, d00 * d11 - d01 ** 2, 1.0)
    w1 = np.clip((d11 * d20 - d01 * d21) / den, 0, 1)
    w2 = np.clip((d00 * d21 - d01 * d20) / den, 0, 1)
    w0 = np.clip(1 - w1 - w2, 0, 1)
    W = np.stack([w0, w1, w2], 1)
    W /= np.maximum(W.sum(1, keepdims=True), 1e-12)
    return np.einsum("ki,kic->kc", W, C_old[F_old[face]])


def _schedule(res_schedule, width):
    """[(fraction, width), ...] sorted; ``None`` means the targets' own resolution throughout."""
    if not res_schedule:
        return [(0.0, width)]
    sched = sorted((float(f), int(w)) for f, w in res_schedule)
    if sched[0][0] > 0:
        sched.insert(0, (0.0, sched[0][1]))
    return sched


# --------------------------------------------------------------------------- the peer

def fit_largesteps(sensors, targets, *, emitter=CONSTANT_EMITTER, budget_s: float, bbox=None, masks=None,
                   init="ico", ico_subdivisions: int = 4, lam: float = 25.0, lr: float = 0.03,
                   res_schedule=None, spp: int = 4, remesh=(0.5,), remesh_factor: float = 0.5,
                   remesher: str = "auto", views_per_step: int = 1, views_per_step_after: int | None = None,
                   sppi_after: int = 0, albedo: float | None = 0.5, lr_albedo: float = 0.02, seed: int = 0,
                   max_steps: int | None = None, clock: str = "wall", progress: bool = True) -> dict:
    """Fit a triangle mesh to multi-view images the way Mitsuba's shape-optimisation tutorial does.

    Parameters
    ----------
    sensors : list of dict
        Mitsuba ``perspective`` sensor dicts with an ``hdrfilm``, one per target (the film's
        pixel format is forced to RGB and ``sample_border`` set, as in the notebook; its
        reconstruction filter is kept).
    targets : list of (h, w, 3) float32 NumPy arrays
        Linear RGB photos, one per sensor, at the sensors' film resolution.
    emitter : dict
        Mitsuba emitter dict of the capture lighting (default: uniform white environment).
    budget_s : float
        Wall-clock budget of the optimisation, remeshing included: a step is not started when
        the previous step's duration would take the run past it. Scene building, target
        upload and the first LargeSteps factorisation are ``setup_s``, outside the budget.
    bbox : ((3,), (3,)) or None
        Box of the subject (the bench's normalised box). Sizes the initial sphere (centre of
        the box, radius half its smallest side) and the step (``lr`` is relative to its
        diagonal). Default: the unit-diagonal cube at the origin.
    masks : list of (h, w) arrays, optional
        Accepted and ignored: the notebook's loss is L1 on the images, background included.
    init : 'ico' or (V, F)
        Starting mesh: an icosphere with ``ico_subdivisions`` (5 is the notebook's 20,480
        faces, 4 is 5,120), or explicit arrays.
    lam : float
        LargeSteps lambda (the notebook's 25), kept after remeshing as in the notebook.
    lr : float
        Adam step of the latent positions, as a fraction of ``bbox``'s diagonal
        (``mi.ad.Adam(lr=lr * diagonal, uniform=True)``, rebuilt after every remesh).
    res_schedule : sequence of (fraction of budget, film width) or None
        Coarse-to-fine rendering resolution, e.g. ``((0, 128), (0.5, 256))``; targets are
        box-averaged down. None (the default, as the notebook, and better in the tuning): the
        targets' resolution throughout.
    spp : int
        Samples per pixel of each differentiable render.
    remesh : sequence of float
        Fractions of the budget at which to remesh (the notebook: once, half-way). ``()`` none.
    remesh_factor : float
        Target edge length of a remesh as a fraction of the current mean edge length (0.5:
        the notebook's; each remesh roughly quadruples the faces).
    remesher : {'auto', 'botsch', 'pymeshlab'}
        'auto': gpytoolbox's Botsch-Kobbelt remesher if importable, else pymeshlab's isotropic
        explicit remeshing.
    views_per_step, views_per_step_after : int
        Views (each its own render and backward pass; projective integrators cannot batch
        sensors) whose gradients make one Adam step, before and after the first remesh
        (None: the same as before). Views are visited in order, cycling.
    sppi_after : int
        ``sppi`` of ``direct_projective`` after the first remesh (the notebook turns
        indirect-visibility gradients on there; 0 keeps them off).
    albedo : float or None
        Fixed grey diffuse albedo of the fitted mesh, or None: optimise a per-vertex RGB albedo
        (``mesh_attribute`` ``vertex_color``, start 0.5, Adam with ``lr_albedo``, clamped to
        [0, 1] after every step).
    lr_albedo : float
        Adam step of the albedo (absolute, in reflectance units).
    seed : int
        Render seeds are ``seed * 1_000_003 + step``.
    max_steps : int or None
        Also stop after this many Adam steps (whichever of budget and steps comes first); the
        schedules then follow ``max(elapsed / budget_s, steps / max_steps)``. For comparing
        settings at equal work on a machine shared with other jobs.
    clock : {'wall', 'cpu'}
        What ``budget_s``, the schedules and ``history`` measure: wall-clock seconds, or this
        process's CPU seconds divided by the cores it may use (``os.sched_getaffinity``): about
        the wall time of a run alone on the machine (it keeps both cores nearly busy: 120 s
        gave 704 steps of wall clock at low load, 714 of CPU clock under heavy load), little
        changed by other jobs. For tuning on a shared machine.
    progress : bool
        A progress line on stderr every few seconds.

    Returns
    -------
    dict
        ``V`` (n, 3) float64, ``F`` (m, 3) int64, ``colors`` ((n, 3) or None), ``history``
        [(t, loss)] (seconds since the start of the optimisation, mean L1 of the step's
        views), ``params`` (optimised scalars of the final mesh: 3 n, plus 3 n with albedo),
        ``steps``, ``remeshes`` [(t, faces before, faces after, seconds)], ``settings``
        (every setting used), ``time_s`` (optimisation wall time), ``cpu_s`` (its CPU time, all
        threads), ``setup_s`` (wall).
    """
    _require_cholespy()
    mi = _mitsuba()
    import drjit as dr

    t_setup = time.perf_counter()
    if len(sensors) != len(targets) or not sensors:
        raise ValueError(f"fit_largesteps(): {len(sensors)} sensors for {len(targets)} targets")
    targets = [np.asarray(t, np.float32)[..., :3] for t in targets]
    H, W = targets[0].shape[:2]
    lo, hi = (np.array(c, np.float64).reshape(3) for c in (bbox if bbox is not None else
                                                            ([-0.5 / 3 ** 0.5] * 3, [0.5 / 3 ** 0.5] * 3)))
    diag = float(np.linalg.norm(hi - lo))
    if isinstance(init, str):
        if init != "ico":
            raise ValueError(f"fit_largesteps(): init must be 'ico' or (V, F), got {init!r}")
        V, F = _icosphere(ico_subdivisions, 0.5 * (lo + hi), 0.5 * float((hi - lo).min()))
    else:
        V, F = np.asarray(init[0], np.float64), np.asarray(init[1], np.int64)
    optimise_albedo = albedo is None
    C = np.full((len(V), 3), 0.5) if optimise_albedo else None
    sched = _schedule(res_schedule, W)
    remesh_at = sorted(float(f) for f in (remesh or ()))
    vps_after = views_per_step if views_per_step_after is None else int(views_per_step_after)

    sensor_cache, target_cache = {}, {}

    def view(k, width):
        if (k, width) not in sensor_cache:
            sensor_cache[k, width] = _sensor(sensors[k], width, spp)
            h = max(1, round(H * width / W))
            target_cache[k, width] = mi.TensorXf(_downsample(targets[k], h, width).astype(np.float32))
        return sensor_cache[k, width], target_cache[k, width]

    integrators = {s: mi.load_dict({"type": "direct_projective", "sppi": int(s)}) for s in {0, int(sppi_after)}}

    def build(V, F, C):
        mesh = _mesh(V, F, C, 0.5 if albedo is None else albedo)
        scene = _scene(mesh, emitter, {"type": "direct_projective", "sppi": 0})
        params = mi.traverse(scene)
        kp = _key(params, "vertex_positions")
        kc = _key(params, "vertex_color") if C is not None else None
        params.keep([kp] + ([kc] if kc else []))
        ls = mi.ad.LargeSteps(params[kp], mi.UInt32(np.asarray(F, np.uint32).ravel()), lam)
        opt = mi.ad.Adam(lr=lr * diag, uniform=True)
        opt["u"] = ls.to_differential(params[kp])
        opt_c = None
        if kc:
            opt_c = mi.ad.Adam(lr=lr_albedo)
            opt_c["c"] = params[kc]
        return scene, params, kp, kc, ls, opt, opt_c

    init_faces = len(F)
    state = build(V, F, C)
    for k in range(len(sensors)):    # film / target copies at every scheduled resolution
        for _, w in sched:
            view(k, w)
    dr.sync_thread()
    setup_s = time.perf_counter() - t_setup

    history, remeshes = [], []
    step, cursor, last_dt, last_print = 0, 0, 0.0, 0.0
    remeshed = 0
    if clock not in ("wall", "cpu"):
        raise ValueError(f"fit_largesteps(): clock must be 'wall' or 'cpu', got {clock!r}")
    cores = len(os.sched_getaffinity(0))

    def now():
        return time.perf_counter() if clock == "wall" else time.process_time() / cores

    wall0, cpu0 = time.perf_counter(), time.process_time()
    t0 = now()
    while True:
        t = now() - t0
        if t + last_dt > budget_s or (max_steps is not None and step >= max_steps):
            break
        frac = max(t / budget_s, step / max_steps if max_steps else 0.0)
        if remeshed < len(remesh_at) and frac >= remesh_at[remeshed]:
            scene, params, kp, kc, ls, opt, opt_c = state
            with dr.suspend_grad():
                params[kp] = ls.from_differential(opt["u"])
                params.update()
            V = params[kp].numpy().reshape(-1, 3).astype(np.float64)
            C = np.clip(opt_c["c"].numpy().reshape(-1, 3), 0, 1).astype(np.float64) if opt_c else None
            tr = now()
            h = remesh_factor * _mean_edge(V, F)
            V2, F2, remesher_used = _remesh(V, F, h, remesher)
            C2 = _transfer_colors(V, F, C, V2) if C is not None else None
            remeshes.append((t, len(F), len(F2), None))
            V, F, C = V2, F2, C2
            state = build(V, F, C)
            remeshes[-1] = (t, remeshes[-1][1], len(F), now() - tr)
            remeshed += 1
            if progress:
                print(f"[peer] t={t:6.1f}s remesh ({remesher_used}): {remeshes[-1][1]} -> {len(F)} faces "
                      f"in {remeshes[-1][3]:.1f}s", file=sys.stderr)
            continue
        width = [w for f, w in sched if f <= frac][-1]
        scene, params, kp, kc, ls, opt, opt_c = state
        n_views = vps_after if remeshed else views_per_step
        integrator = integrators[int(sppi_after) if remeshed else 0]
        ts = now()
        total = 0.0
        for _ in range(n_views):
            k = cursor % len(sensors)
            cursor += 1
            sensor, target = view(k, width)
            params[kp] = ls.from_differential(opt["u"])
            if kc:
                params[kc] = opt_c["c"]
            params.update()
            img = mi.render(scene, params, sensor=sensor, spp=spp, seed=seed * 1_000_003 + step,
                            integrator=integrator)
            loss = dr.mean(dr.abs(img - target).array) / n_views
            dr.backward(loss)
            total += float(loss[0])
        opt.step()
        if opt_c is not None:
            opt_c.step()
            opt_c["c"] = dr.clip(opt_c["c"], 0.0, 1.0)
        dr.eval(opt["u"])
        dr.sync_thread()
        step += 1
        last_dt = now() - ts
        t = now() - t0
        history.append((t, total))
        if progress and t - last_print > 10:
            last_print = t
            print(f"[peer] t={t:6.1f}s step {step} res {width} faces {len(F)} loss {total:.5f} "
                  f"({last_dt:.2f}s/step)", file=sys.stderr)
    time_s = time.perf_counter() - wall0
    cpu_s = time.process_time() - cpu0

    scene, params, kp, kc, ls, opt, opt_c = state
    with dr.suspend_grad():
        V = ls.from_differential(opt["u"]).numpy().reshape(-1, 3).astype(np.float64)
    C = np.clip(opt_c["c"].numpy().reshape(-1, 3), 0, 1).astype(np.float64) if opt_c else None
    settings = {
        "pipeline": "mitsuba-tutorials inverse_rendering/shape_optimization.ipynb (LargeSteps + remesh)",
        "init": init if isinstance(init, str) else "explicit", "ico_subdivisions": int(ico_subdivisions),
        "init_faces": init_faces, "lam": float(lam), "lr": float(lr), "lr_abs": float(lr * diag),
        "bbox_diagonal": diag, "optimizer": "mi.ad.Adam(uniform=True) on LargeSteps latent u",
        "res_schedule": [list(s) for s in sched], "spp": int(spp), "remesh": remesh_at,
        "remesh_factor": float(remesh_factor), "remesher": remesher,
        "remesher_used": remesher_used if remeshes else None, "views_per_step": int(views_per_step),
        "views_per_step_after": int(vps_after), "view_order": "cyclic, in the given order",
        "integrator": {"type": "direct_projective", "sppi": 0}, "sppi_after": int(sppi_after),
        "loss": "mean L1 over pixels and RGB (background included)", "masks": "ignored",
        "albedo": "optimised per vertex" if optimise_albedo else float(albedo),
        "lr_albedo": float(lr_albedo) if optimise_albedo else None, "seed": int(seed),
        "budget_s": float(budget_s), "clock": clock, "max_steps": max_steps, "n_views": len(sensors),
        "target_resolution": [int(W), int(H)],
        "film": "rgb, sample_border=True, sensor's reconstruction filter",
        "normals": "smooth vertex normals recomputed by Mitsuba after every update",
    }
    params_count = 3 * len(V) * (2 if optimise_albedo else 1)
    return {"V": V, "F": np.asarray(F, np.int64), "colors": C, "history": history, "params": params_count,
            "steps": step, "remeshes": remeshes, "settings": settings, "time_s": time_s, "cpu_s": cpu_s,
            "setup_s": setup_s}


# --------------------------------------------------------------------------- helpers for benches and tests

def image_l1(V, F, sensors, targets, *, emitter=CONSTANT_EMITTER, albedo=0.5, colors=None, spp: int = 16,
             seed: int = 12345) -> float:
    """Mean L1 between renders of a mesh (``direct``, smooth normals) and the targets, over all views."""
    mi = _mitsuba()
    import drjit as dr

    scene = _scene(_mesh(V, F, colors, albedo), emitter, {"type": "direct"})
    total = 0.0
    with dr.suspend_grad():
        for k, (s, t) in enumerate(zip(sensors, targets)):
            img = mi.render(scene, sensor=_sensor(s, None, spp, sample_border=False), spp=spp, seed=seed + k)
            total += float(np.abs(np.asarray(img) - np.asarray(t, np.float32)[..., :3]).mean())
    return total / len(sensors)


def render_targets(V, F, sensors, *, emitter=CONSTANT_EMITTER, albedo=0.5, colors=None, spp: int = 64,
                   seed: int = 0):
    """Render a target mesh from every sensor with ``direct`` (smooth vertex normals); list of (h, w, 3)."""
    mi = _mitsuba()

    scene = _scene(_mesh(V, F, colors, albedo), emitter, {"type": "direct"})
    return [np.asarray(mi.render(scene, sensor=_sensor(s, None, spp, sample_border=False), spp=spp,
                                 seed=10_000 * seed + k), dtype=np.float32) for k, s in enumerate(sensors)]


def fibonacci_sensors(n: int, resolution: int = 256, *, distance: float = 2.5, fov: float = 35.0, centre=(0, 0, 0),
                      rfilter: str = "box") -> list:
    """``n`` perspective sensor dicts looking at ``centre`` from a Fibonacci sphere (the notebook's lattice)."""
    mi = _mitsuba()

    golden = (1 + 5 ** 0.5) / 2
    out = []
    c = np.asarray(centre, np.float64)
    for i in range(n):
        theta = 2 * math.pi * i / golden
        phi = math.acos(1 - 2 * (i + 0.5) / n)
        o = c + distance * np.array([math.cos(theta) * math.sin(phi), math.sin(theta) * math.sin(phi), math.cos(phi)])
        out.append({"type": "perspective", "fov": float(fov),
                    "to_world": mi.ScalarTransform4f().look_at(origin=o.tolist(), target=c.tolist(), up=[0, 1, 0]),
                    "film": {"type": "hdrfilm", "width": int(resolution), "height": int(resolution),
                             "pixel_format": "rgb", "rfilter": {"type": rfilter}}})
    return out


def normalise(V):
    """Centre a point set's bounding box at the origin and scale its diagonal to 1."""
    V = np.asarray(V, np.float64)
    lo, hi = V.min(0), V.max(0)
    return (V - 0.5 * (lo + hi)) / np.linalg.norm(hi - lo)


def load_target(path):
    """A mesh file as (V, F), merged duplicate vertices, normalised (:func:`normalise`)."""
    import trimesh

    m = trimesh.load(str(path), force="mesh", process=True)
    return normalise(m.vertices), np.asarray(m.faces, np.int64)


def _main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("target", help="mesh file (normalised to the origin, unit bbox diagonal)")
    p.add_argument("--budget", type=float, default=120.0)
    p.add_argument("--views", type=int, default=16)
    p.add_argument("--res", type=int, default=256)
    p.add_argument("--target-spp", type=int, default=64)
    p.add_argument("--fov", type=float, default=35.0)
    p.add_argument("--distance", type=float, default=2.5, help="camera distance in bbox diagonals")
    p.add_argument("--lam", type=float, default=25.0)
    p.add_argument("--lr", type=float, default=0.03)
    p.add_argument("--spp", type=int, default=4)
    p.add_argument("--ico", type=int, default=4, help="icosphere subdivisions of the start")
    p.add_argument("--res-schedule", default="none", help="'frac:width,...' (e.g. 0:128,0.5:256) or 'none'")
    p.add_argument("--remesh", default="0.5", help="budget fractions, comma separated, or 'none'")
    p.add_argument("--remesh-factor", type=float, default=0.5)
    p.add_argument("--remesher", default="auto")
    p.add_argument("--vps", type=int, default=1, help="views per step")
    p.add_argument("--vps-after", type=int, default=None)
    p.add_argument("--sppi-after", type=int, default=0)
    p.add_argument("--albedo", default="0.5", help="grey albedo or 'opt'")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--max-steps", type=int, default=None)
    p.add_argument("--clock", default="wall", choices=("wall", "cpu"))
    p.add_argument("--label", default="")
    p.add_argument("--json", help="append one JSON line of settings and metrics")
    p.add_argument("--save", help="write the fitted mesh (PLY)")
    a = p.parse_args(argv)

    mi = _mitsuba()
    from mi_loop import metrics

    Vt, Ft = load_target(a.target)
    diag = float(np.linalg.norm(np.ptp(Vt, 0)))
    sensors = fibonacci_sensors(a.views, a.res, distance=a.distance * diag, fov=a.fov)
    load0 = os.getloadavg()
    t = time.perf_counter()
    targets = render_targets(Vt, Ft, sensors, spp=a.target_spp)
    print(f"[peer] targets: {a.views} x {a.res}^2 at {a.target_spp} spp in {time.perf_counter() - t:.1f}s",
          file=sys.stderr)
    sched = None if a.res_schedule == "none" else [tuple(float(x) for x in s.split(":"))
                                                     for s in a.res_schedule.split(",")]
    remesh = () if a.remesh == "none" else tuple(float(x) for x in a.remesh.split(","))
    out = fit_largesteps(sensors, targets, emitter=CONSTANT_EMITTER, budget_s=a.budget, bbox=(Vt.min(0), Vt.max(0)),
                         ico_subdivisions=a.ico, lam=a.lam, lr=a.lr, res_schedule=sched, spp=a.spp, remesh=remesh,
                         remesh_factor=a.remesh_factor, remesher=a.remesher, views_per_step=a.vps,
                         views_per_step_after=a.vps_after, sppi_after=a.sppi_after,
                         albedo=None if a.albedo == "opt" else float(a.albedo), seed=a.seed,
                         max_steps=a.max_steps, clock=a.clock)
    load = os.getloadavg()
    d = metrics.two_sided(out["V"], out["F"], Vt, Ft, n_samples=30_000, seed=0)
    hist = np.array(out["history"])
    row = {"label": a.label, "target": Path(a.target).name, "budget": a.budget, "mean": d["mean"], "rms": d["rms"],
           "hausdorff": d["hausdorff"], "steps": out["steps"], "faces": len(out["F"]), "params": out["params"],
           "time_s": out["time_s"], "cpu_s": out["cpu_s"], "setup_s": out["setup_s"],
           "load_before": round(load0[0], 2), "load_after_5min": round(load[1], 2), "remeshes": out["remeshes"],
           "loss_first": float(hist[:16, 1].mean()) if len(hist) else None,
           "loss_last": float(hist[-16:, 1].mean()) if len(hist) else None, "settings": out["settings"]}
    print(json.dumps({k: v for k, v in row.items() if k != "settings"}))
    if a.json:
        with open(a.json, "a") as fh:
            fh.write(json.dumps(row) + "\n")
    if a.save:
        import trimesh

        trimesh.Trimesh(out["V"], out["F"], process=False).export(a.save)
    del mi


if __name__ == "__main__":
    _main()
