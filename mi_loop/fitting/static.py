"""Fit a Loop control mesh to oriented points: IMLS distance, coverage, ARAP and a fold barrier, Adam in Dr.Jit.

No file I/O here (see :mod:`mi_loop.io` and :mod:`mi_loop.io.points`); the CLI
passes a progress callback.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from mi_loop.errors import FitError
from mi_loop.fitting.noise import ALPHA_CLEAN, RATIO_CLEAN, noise_estimate, template_options
from mi_loop.fitting.options import SAMPLE_MODES, FitOptions, OptionError
from mi_loop.fitting.selection import ALPHAS, MIN_POINTS, held_out_split, select_alpha
from mi_loop.mesh.checks import check_oriented_points
from mi_loop.mesh.geometry import mean_edge_length
from mi_loop.mesh.sampling import surface_distances
from mi_loop.mesh.topology import validate_mesh
from mi_loop.subdiv.masks import limit_mesh, vertex_samples
from mi_loop.subdiv.tessellation import tessellate

__all__ = ["FOLD_COSINE", "FOLD_LEVEL", "FitResult", "Normalisation", "fit", "sample_parameters"]

#: Tessellation level of the fold barrier's samples (``4**level`` per control face).
FOLD_LEVEL = 2
#: The barrier acts on limit normals whose cosine to the nearest data normal is below this.
FOLD_COSINE = 0.5
#: Data normals averaged into each reference normal.
FOLD_NEIGHBOURS = 8
#: Tessellation level of the limit surface measured against held-out points (selection of ``alpha``).
SELECTION_LEVEL = 2


@dataclass
class Normalisation:
    """Map data to the unit box (largest extent 1, centred at 0) and back.

    Attributes
    ----------
    centre : (3,) float64 NumPy array
        Centre of the data's bounding box.
    scale : float
        Largest extent of the data's bounding box.

    Examples
    --------
    >>> norm = Normalisation.of(np.array([[0.0, 0, 0], [4, 2, 0]]))
    >>> norm.forward([[4.0, 2, 0]]).tolist(), norm.inverse([[0.5, 0.25, 0]]).tolist()
    ([[0.5, 0.25, 0.0]], [[4.0, 2.0, 0.0]])
    """

    centre: np.ndarray
    scale: float

    @classmethod
    def of(cls, P: np.ndarray) -> Normalisation:
        """The normalisation of points ``P`` (``(k, 3)`` float NumPy array)."""
        lo, hi = P.min(0), P.max(0)
        return cls((lo + hi) / 2.0, float((hi - lo).max()))

    def forward(self, X):
        """``(X - centre) / scale``: from the data's units to the unit box."""
        return (np.asarray(X) - self.centre) / self.scale

    def inverse(self, X):
        """``X * scale + centre``: from the unit box back to the data's units."""
        return np.asarray(X) * self.scale + self.centre


@dataclass
class FitResult:
    """Outcome of :func:`fit`.

    Attributes
    ----------
    V : (n, 3) float64 numpy array
        Fitted control points, in the input's units.
    F : (m, 3) int64 numpy array
        Control faces.
    V_template : (n, 3) float64 numpy array
        Control points before fitting, in the input's units.
    history : dict of lists
        Per iteration: ``imls``, ``cover``, ``arap``, ``fold`` (the weighted
        terms) and ``total`` energies, ``lr``.
    timings : dict
        Seconds per stage.
    params : dict
        Parameters actually used (after automatic choices).
    info : dict
        What the template was built from (``info["template"]``) and the noise
        level of the data (``info["noise"]``: ``sigma`` and ``spacing`` in the
        data's units, their ``ratio``, ``sigma_diagonal``, ``alpha``: whether
        the weight was given, the clean-data one or selected, and then
        ``selection``: the candidates tried and their held-out distances).
    converged : bool
        True when a stopping rule ended the loop (no more relative improvement
        than ``tolerance``); False when it ran into ``iterations``.
    creases : (c, 2) int64 numpy array or None
        Infinitely sharp crease edges of the control mesh (sharp features).
    """

    V: np.ndarray
    F: np.ndarray
    V_template: np.ndarray
    history: dict
    timings: dict
    params: dict
    info: dict = field(default_factory=dict)
    converged: bool = False
    creases: np.ndarray | None = None

    def limit_mesh(self, level: int = 3):
        """Dense limit mesh ``(V_lim, F_lim, N_lim)`` of the fitted surface (NumPy), creases included."""
        return limit_mesh(self.V, self.F, level, creases=self.creases)


def sample_parameters(F: np.ndarray, n_vertices: int, mode: str, seed: int = 0):
    """Return the limit-sample parameters ``(face_ids, uv)`` of a sampling ``mode``.

    Parameters
    ----------
    F : (m, 3) int NumPy array
        Control faces.
    n_vertices : int
        Number of control vertices.
    mode : {'vertices', 'level1', 'random'}
        ``'vertices'``: one sample per control vertex (its limit point, the
        thesis's default); ``'level1'``: the points of a level-1
        tessellation; ``'random'``: four uniformly random points per face.
    seed : int, optional
        Seed of ``'random'`` (NumPy ``default_rng``).

    Returns
    -------
    face_ids : (k,) int NumPy array
    uv : (k, 2) float64 NumPy array
        Barycentric ``(u, v)`` in each face, ``u, v >= 0``, ``u + v <= 1``.

    Raises
    ------
    ValueError
        If ``mode`` is not one of :data:`~mi_loop.fitting.options.SAMPLE_MODES`.
    """
    if mode == "vertices":
        return vertex_samples(F, n_vertices)
    if mode == "level1":
        fid, uv, _ = tessellate(F, 1)
        return fid, uv
    if mode == "random":
        rng = np.random.default_rng(seed)
        fid = np.repeat(np.arange(len(F)), 4)
        uv = rng.random((len(fid), 2))
        flip = uv.sum(1) > 1
        uv[flip] = 1.0 - uv[flip]
        return fid, uv
    raise ValueError(f"fit(): samples must be one of {SAMPLE_MODES}, got {mode!r}")


def fit(points, normals, *, n_vertices: int = FitOptions.n_vertices, template=None,
        alpha: float = FitOptions.alpha, h0: float | None = FitOptions.h0, samples: str = FitOptions.samples,
        iterations: int = FitOptions.iterations, tolerance: float = FitOptions.tolerance,
        cover: float = FitOptions.cover, seed: int = FitOptions.seed, fold: float = FitOptions.fold,
        features: str = FitOptions.features, mesh=None, creases=None,
        progress=None) -> FitResult:
    """Fit a Loop control mesh to oriented points.

    Minimises ``E = mean_j f(Q_j)^2 + cover * E_cover + alpha * E_arap(V0) / n + fold * E_fold``
    over the control points ``V0`` where ``Q = W V0`` are exact limit samples,
    ``f`` is the IMLS function of the data (Xie 2022, eqs. 8-13),
    ``E_cover`` the data-to-sample coverage term (:mod:`mi_loop.energies.coverage`)
    and ``E_fold`` the barrier on limit normals turned by more than 60 degrees
    from the normals of the nearest data points (:mod:`mi_loop.energies.fold`),
    with Adam (Dr.Jit). The keyword arguments are the fields of
    :class:`~mi_loop.fitting.options.FitOptions` (defaults and checks there),
    so ``fit(P, N, **dataclasses.asdict(options))`` runs ``options``.

    Parameters
    ----------
    points : (N, 3) float numpy array
        Data points.
    normals : (N, 3) float numpy array
        Unit normals at the data points (oriented outward).
    n_vertices : int
        Control vertices of the automatic template (ignored with ``template``).
    template : tuple ``(V, F)``, optional
        Control mesh to start from, in the data's units.
    features : {'auto', 'off'}
        With ``mesh`` and no ``template``: ``'auto'`` looks for sharp feature
        curves in ``mesh`` and, when there are any, starts from
        :func:`~mi_loop.fitting.template.feature_template` with its control
        edges along them as infinitely sharp creases; ``'off'`` never does.
    mesh : tuple ``(V, F)``, optional
        The surface mesh the points were sampled from, in the data's units
        (for feature detection).
    creases : (c, 2) int array, optional
        Infinitely sharp crease edges of ``template``.
    alpha : float, optional
        ARAP weight; automatic by default: 0.001 on clean data (noise below a
        tenth of the point spacing, :mod:`mi_loop.fitting.noise`), otherwise
        the best of 0.001, 0.01, 0.1, 1 on a tenth of the points held out of
        the fit (:mod:`mi_loop.fitting.selection`); ``info['noise']`` says
        which and what was measured.
    h0 : float, optional
        IMLS support radius in the unit box; automatic from the point spacing.
    samples : {'vertices', 'level1', 'random'}
        Limit samples in the distance term: ``'level1'`` (default, the points
        of a level-1 tessellation, about 4x the control vertices: closer fits,
        fewer bulges between vertices) or ``'vertices'`` (the thesis's default,
        faster).
    iterations : int
        Iteration cap; the loop normally stops on relative improvement.
    tolerance : float
        Relative improvement of the best energy below which the step halves
        (after 12 iterations without it) and the loop stops (over 40
        iterations, or after three halvings).
    cover : float
        Weight of the coverage term (:mod:`mi_loop.energies.coverage`): every data
        point pulls its nearest limit sample along its normal, so thin parts
        of the data are not left uncovered (default 3). 0 turns it off.
    seed : int
        Seed for random sampling.
    fold : float
        Weight of the fold barrier (default 0.01): a fold (an inside-out
        strip of the limit surface) can lie on the data, where the distance
        terms do not see it. It acts on the limit normals at a level-2
        tessellation (:data:`FOLD_LEVEL`), against the mean normal of the 8
        nearest data points (:data:`FOLD_NEIGHBOURS`). 0 turns it off; so
        does a template with sharp features (``features``), whose averaged
        reference normals point between the two sides of every sharp edge.
    progress : callable, optional
        Called as ``progress(iteration, iterations, energy)``.

    Returns
    -------
    FitResult

    Raises
    ------
    ValueError
        Invalid data, options or template
        (:class:`~mi_loop.fitting.options.OptionError` for an option).
    FitError
        If the optimisation diverges (non-finite energy) and cannot recover.
    """
    import drjit as dr  # noqa: F401  (loaded before the stage timers start)
    import mitsuba as mi  # noqa: F401

    from mi_loop.ad.operator import LimitOperator
    from mi_loop.energies.arap import ARAP
    from mi_loop.energies.coverage import Coverage
    from mi_loop.energies.imls import IMLS

    t_all = time.perf_counter()
    timings = {}
    P, N = check_oriented_points(points, normals, "fit")
    try:
        FitOptions(n_vertices=n_vertices, alpha=alpha, h0=h0, samples=samples, iterations=iterations,
                   tolerance=tolerance, cover=cover, seed=seed, fold=fold, features=features)
    except OptionError as exc:
        raise exc.renamed("fit") from None
    _check_template(template)
    norm = Normalisation.of(P)
    Pn = norm.forward(P)

    t = time.perf_counter()
    noise = {**noise_estimate(P), "alpha": "given" if alpha is not None else "clean data"}    # the data's units
    timings["noise"] = time.perf_counter() - t

    t = time.perf_counter()
    found = None
    if template is None and mesh is not None and features == "auto":
        from mi_loop.fitting.template import feature_template

        found = feature_template(mesh[0], mesh[1], n_vertices)    # in the data's units: the decimation
    if found is not None:                 # is not scale-invariant (the fandisk normalised got 252 creases, not 266)
        V0, F, creases, tinfo = found     # sharp features: a planar-quadric template with creases along them
        V0 = norm.forward(V0)
        tinfo = {"source": "mesh with sharp features", **tinfo, "fold": "off: the creases hold the features"}
        fold = 0.0      # its averaged reference normals fight sharp edges (fandisk: NAE 0.77 -> 1.89 with it)
    elif template is None:
        from mi_loop.fitting.template import make_template

        V0, F, tinfo = make_template(Pn, N, n_vertices, seed=seed, **template_options(noise["ratio"]))
        creases = None
    else:
        V0, F = template
        V0, F, _ = validate_mesh(V0, F, "fit")
        V0 = norm.forward(V0)
        tinfo = {"source": "user"}
    timings["template"] = time.perf_counter() - t

    t = time.perf_counter()
    fid, uv = sample_parameters(F, len(V0), samples, seed)
    op = LimitOperator(F, len(V0), fid, uv, creases=creases, derivatives=False)
    fold_op = None
    if fold > 0:      # the barrier's samples: denser than the distance terms', so small folds show
        fid_f, uv_f, _ = tessellate(F, FOLD_LEVEL)
        fold_op = LimitOperator(F, len(V0), fid_f, uv_f, creases=creases, derivatives=True)
    timings["operator"] = time.perf_counter() - t

    t = time.perf_counter()
    imls = IMLS(Pn, N, h0=h0)
    coverage = Coverage(Pn, N, tree=imls.tree) if cover > 0 else None
    arap = ARAP(V0, F)
    timings["energies"] = time.perf_counter() - t

    def fit_with(energies, a, step):
        data, cov = energies                # (IMLS, Coverage or None) of all the points, or of the kept ones
        weights = {"alpha": a, "cover": cover if cov is not None else 0.0, "fold": float(fold)}
        return _optimise(op, fold_op, data, arap, cov, V0, weights, iterations, tolerance, step)

    t = time.perf_counter()
    if alpha is None and noise["ratio"] > RATIO_CLEAN and len(Pn) >= MIN_POINTS:
        alpha, noise["selection"] = _select(Pn, N, F, creases, h0, cover, fit_with, seed, progress)
        noise["alpha"] = f"selected on {noise['selection']['held_out_points']} held-out points"
        timings["selection"] = time.perf_counter() - t
        t = time.perf_counter()
        if progress is not None:
            shown, progress = progress, (lambda i, n, E: shown(len(ALPHAS) * n + i, (len(ALPHAS) + 1) * n, E))
    alpha = ALPHA_CLEAN if alpha is None else float(alpha)
    V, history, converged = fit_with((imls, coverage), alpha, progress)
    timings["optimisation"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - t_all
    params = {"n_vertices": int(len(V0)), "n_faces": int(len(F)), "alpha": alpha,
              "h0": float(imls.h0), "samples": samples, "n_samples": int(len(fid)),
              "iterations": iterations, "tolerance": tolerance, "cover": cover, "seed": seed, "fold": fold,
              "iterations_run": len(history["total"]), "normalisation_scale": norm.scale,
              "features": features, "n_creases": 0 if creases is None else int(len(creases))}
    return FitResult(norm.inverse(V), F, norm.inverse(V0), history, timings, params,
                     {"template": tinfo, "noise": noise}, converged,
                     None if creases is None else np.asarray(creases))


def _select(Pn, N, F, creases, h0, cover, fit_with, seed, progress):
    """The ARAP weight whose fit to nine tenths of the points lies closest to the other tenth; ``(alpha, tried)``."""
    from mi_loop.energies.coverage import Coverage
    from mi_loop.energies.imls import IMLS

    held = held_out_split(len(Pn), seed)
    imls = IMLS(Pn[~held], N[~held], h0=h0)
    energies = (imls, Coverage(Pn[~held], N[~held], tree=imls.tree) if cover > 0 else None)

    def held_out_error(V):
        return surface_distances(*limit_mesh(V, F, SELECTION_LEVEL, creases=creases)[:2], Pn[held]).mean()

    # one bar for the candidates and the final fit: the candidates' share, then the final fit's
    step = None if progress is None else (lambda i, n, E: progress(i, n + n // len(ALPHAS), E))
    alpha, _, tried = select_alpha(lambda a, s: fit_with(energies, a, s), held_out_error, progress=step)
    return alpha, {**tried, "held_out_points": int(held.sum())}


def _reference_normals(imls, Q):
    """The fold barrier's reference normals at samples ``Q`` ((k, 3) NumPy): ``mi.Normal3f``."""
    import mitsuba as mi

    from mi_loop.ad.upload import upload_vec
    from mi_loop.energies.fold import nearest_data_normals

    return upload_vec(mi.Normal3f, nearest_data_normals(imls.tree, imls.normals, Q, FOLD_NEIGHBOURS))


def _check_template(template):
    if template is not None and not (isinstance(template, (tuple, list)) and len(template) == 2):
        raise ValueError("fit(): expected template to be a pair (V, F) of control points and faces, got "
                         f"{type(template).__name__}")


def _optimise(op, fold_op, imls, arap, coverage, V0, weights, iterations, tolerance, progress):
    """Adam on the control points; ``weights`` holds ``alpha``, ``cover`` and ``fold``.

    Schedule: the first step size is a third of the initial RMS IMLS residual
    (the distance the surface has to move), capped by a twentieth of the mean
    control edge; when the best energy has not improved by ``tolerance``
    (relative) for ``patience`` iterations the step halves and the iterate
    returns to the best one; after three halvings, or when the best energy
    improved by less than ``tolerance`` over the last 40 iterations, it stops.
    A non-finite energy restores the best iterate with a quarter of the step.
    The fold barrier's reference normals (those of the data points nearest to
    the samples) are refreshed with the IMLS neighbourhoods.
    """
    import drjit as dr
    import mitsuba as mi

    from mi_loop.ad.control import ControlPoints
    from mi_loop.energies.fold import fold_energy

    n = len(V0)
    alpha_t = dr.opaque(mi.Float, weights["alpha"] / n)
    cover, fold = weights["cover"], weights["fold"]
    history = {"imls": [], "cover": [], "arap": [], "fold": [], "total": [], "lr": []}
    best_E, best_V = np.inf, V0.copy()
    best_at, decays, recoveries = 0, 0, 0
    patience = 12
    x0 = mi.Float(V0.ravel().astype(np.float32))
    refresh_at = np.array(op.positions(x0), dtype=np.float64).T
    imls.update(refresh_at)
    if coverage is not None:
        coverage.update(refresh_at)
    reference = None
    if fold:
        fold_at = np.array(fold_op.positions(x0), dtype=np.float64).T
        reference = _reference_normals(imls, fold_at)
    e0 = float(imls.energy(op.positions(x0), reduce="mean")[0])
    if not np.isfinite(e0):
        raise FitError("fit(): the optimisation diverged (non-finite energy); "
                       "try a smaller --alpha or another template")
    lr = float(np.clip(np.sqrt(e0) / 3.0, 1e-6, 0.05 * mean_edge_length(V0, arap.F)))
    opt = dr.opt.Adam(lr=lr, params={"x": x0})
    for it in range(iterations):
        x = ControlPoints(opt["x"])       # shared by the limit operator and ARAP
        Q = op.positions(x)
        Q_fold, normals = fold_op.positions_normals(x) if fold else (None, None)
        Vn = x.numpy()
        Qn = np.array(Q, dtype=np.float64).T
        if np.abs(Qn - refresh_at).max() > 0.25 * imls.h0 or it % 20 == 0:
            imls.update(Qn)
            if coverage is not None:
                coverage.update(Qn)
            if fold:
                fold_at = np.array(Q_fold, dtype=np.float64).T
                reference = _reference_normals(imls, fold_at)
            refresh_at = Qn
        terms = [imls.energy(Q, reduce="mean"),
                 cover * coverage.energy(Q) if coverage is not None else mi.Float(0.0),
                 alpha_t * arap.energy(x, arap.rotations(Vn)),
                 fold * fold_energy(normals, reference, FOLD_COSINE) if fold else mi.Float(0.0)]
        E = terms[0] + terms[1] + terms[2] + terms[3]
        dr.eval(*terms, E)
        values = (*(float(t[0]) for t in terms), float(E[0]))
        if not (np.all(np.isfinite(values)) and np.isfinite(Vn).all()):
            recoveries += 1
            if recoveries > 5:
                raise FitError("fit(): the optimisation diverged (non-finite energy); "
                               "try a smaller --alpha or another template")
            lr *= 0.25
            opt = dr.opt.Adam(lr=lr, params={"x": mi.Float(best_V.ravel().astype(np.float32))})
            continue
        dr.backward(E)
        for key, val in zip(("imls", "cover", "arap", "fold", "total"), values):
            history[key].append(val)
        history["lr"].append(lr)
        if values[-1] < best_E * (1.0 - tolerance):
            best_at = it
        if values[-1] < best_E:
            best_E, best_V = values[-1], Vn
        if progress is not None:
            progress(it + 1, iterations, values[-1])
        if it - best_at > patience:
            decays += 1
            if decays > 3:
                return best_V, history, True
            lr *= 0.5
            best_at = it
            opt = dr.opt.Adam(lr=lr, params={"x": mi.Float(best_V.ravel().astype(np.float32))})
            continue
        window = 40
        if it > window and history["total"][-window - 1] > 0:
            old = min(history["total"][:-window])
            if old - best_E < tolerance * old:
                return best_V, history, True
        opt.step()
    return best_V, history, False
