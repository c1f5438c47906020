"""Fit a Loop control mesh to oriented points: IMLS distance, coverage, ARAP and a fold barrier, Adam in Dr.Jit.

No file I/O here (see :mod:`mi_loop.io` and :mod:`mi_loop.io.points`); the CLI
passes a progress callback.
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np

from mi_loop.errors import fail
from mi_loop.fitting.noise import ALPHA_CLEAN, RATIO_CLEAN, noise_estimate, template_options
from mi_loop.fitting.options import SAMPLE_MODES, FitOptions
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


def fit(points, normals, options: FitOptions | None = None, *, template=None, mesh=None, creases=None,
        progress=None) -> FitResult:
    """Fit a Loop control mesh to oriented points.

    Minimises ``E = mean_j f(Q_j)^2 + cover * E_cover + alpha * E_arap(V0) / n + fold * E_fold``
    over the control points ``V0`` where ``Q = W V0`` are exact limit samples,
    ``f`` is the IMLS function of the data (Xie 2022, eqs. 8-13),
    ``E_cover`` the data-to-sample coverage term (:mod:`mi_loop.energies.coverage`)
    and ``E_fold`` the barrier on limit normals turned by more than 60 degrees
    from the normals of the nearest data points (:mod:`mi_loop.energies.fold`),
    with Adam in the optimisation loop of :mod:`mi_loop.fitting.loop`: the
    first step size is a third of the initial RMS IMLS residual (the distance
    the surface has to move), capped by a twentieth of the mean control edge;
    the step halves (back to the best iterate) when the energy has not improved
    by ``tolerance`` for 12 iterations, and the loop stops after three halvings
    or when the best energy improved by less than ``tolerance`` over 40
    iterations. The IMLS neighbourhoods, coverage assignments and fold
    references are rebuilt every 20 iterations and whenever a sample moved by
    a quarter of the IMLS radius. A non-finite energy restores the best iterate
    with a quarter of the step (five times at most).

    Parameters
    ----------
    points : (N, 3) float numpy array
        Data points.
    normals : (N, 3) float numpy array
        Unit normals at the data points (oriented outward).
    options : FitOptions, optional
        Every weight and setting (defaults and checks there). ``alpha=None``
        chooses the ARAP weight: 0.001 on clean data (noise below a tenth of the
        point spacing, :mod:`mi_loop.fitting.noise`), otherwise the best of
        0.001, 0.01, 0.1, 1 on a tenth of the points held out of the fit
        (:mod:`mi_loop.fitting.selection`); ``info['noise']`` says which and what
        was measured. ``fold`` is off for a template with sharp features, whose
        averaged reference normals point between the two sides of every sharp edge.
    template : tuple ``(V, F)``, optional
        Control mesh to start from, in the data's units (``options.n_vertices`` is then ignored).
    mesh : tuple ``(V, F)``, optional
        The surface mesh the points were sampled from, in the data's units:
        with ``options.features == 'auto'`` and no ``template``, its sharp
        feature curves, if any, give a template with infinitely sharp creases
        along them (:func:`~mi_loop.fitting.template.feature_template`).
    creases : (c, 2) int array, optional
        Infinitely sharp crease edges of ``template``.
    progress : callable, optional
        Called as ``progress(iteration, iterations, energy)``.

    Returns
    -------
    FitResult

    Raises
    ------
    TypeError
        ``options`` not a :class:`FitOptions`.
    ValueError
        Invalid data or template.
    FitError
        If the optimisation diverges (non-finite energy) and cannot recover.

    Examples
    --------
    >>> import mi_loop
    >>> from mi_loop.datasets import noisy_torus_points
    >>> mi_loop.set_variant("llvm_ad_rgb")
    >>> P, N, _ = noisy_torus_points(n_points=3000, seed=1)
    >>> result = fit(P, N, FitOptions(n_vertices=100, iterations=30))
    >>> result.V.shape[1], result.params["iterations_run"] <= 30
    (3, True)
    """
    import drjit as dr  # noqa: F401  (loaded before the stage timers start)
    import mitsuba as mi  # noqa: F401

    from mi_loop.energies.arap import ARAP
    from mi_loop.energies.coverage import Coverage
    from mi_loop.energies.imls import IMLS

    options = FitOptions() if options is None else options
    if not isinstance(options, FitOptions):
        fail("fit", "options to be a FitOptions", type(options).__name__, TypeError)
    t_all = time.perf_counter()
    timings = {}
    P, N = check_oriented_points(points, normals, "fit")
    _check_template(template)
    norm = Normalisation.of(P)
    Pn = norm.forward(P)

    t = time.perf_counter()
    noise = {**noise_estimate(P), "alpha": "given" if options.alpha is not None else "clean data"}
    timings["noise"] = time.perf_counter() - t

    t = time.perf_counter()
    V0, F, creases, tinfo = _start(Pn, N, norm, options, template, mesh, creases, noise)
    fold = 0.0 if "feature_curves" in tinfo else options.fold
    timings["template"] = time.perf_counter() - t

    t = time.perf_counter()
    ops = _operators(F, len(V0), creases, options, fold)
    timings["operator"] = time.perf_counter() - t

    t = time.perf_counter()
    imls = IMLS(Pn, N, h0=options.h0)
    coverage = Coverage(Pn, N, tree=imls.tree) if options.cover > 0 else None
    arap = ARAP(V0, F)
    timings["energies"] = time.perf_counter() - t

    def fit_with(energies, a, step):
        return _minimise(ops, energies, arap, V0, a, fold, options, step)

    t = time.perf_counter()
    alpha = options.alpha
    if alpha is None and noise["ratio"] > RATIO_CLEAN and len(Pn) >= MIN_POINTS:
        alpha, noise["selection"] = _select(Pn, N, F, creases, options, fit_with, progress)
        noise["alpha"] = f"selected on {noise['selection']['held_out_points']} held-out points"
        timings["selection"] = time.perf_counter() - t
        t = time.perf_counter()
        if progress is not None:
            shown, progress = progress, (lambda i, n, E: shown(len(ALPHAS) * n + i, (len(ALPHAS) + 1) * n, E))
    alpha = ALPHA_CLEAN if alpha is None else float(alpha)
    V, history, converged = fit_with((imls, coverage), alpha, progress)
    timings["optimisation"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - t_all
    params = {**asdict(options), "n_vertices": int(len(V0)), "n_faces": int(len(F)), "alpha": alpha,
              "h0": float(imls.h0), "n_samples": ops[0].n_samples,
              "fold": fold, "iterations_run": len(history["total"]), "normalisation_scale": norm.scale,
              "n_creases": 0 if creases is None else int(len(creases))}
    return FitResult(norm.inverse(V), F, norm.inverse(V0), history, timings, params,
                     {"template": tinfo, "noise": noise}, converged,
                     None if creases is None else np.asarray(creases))


def _start(Pn, N, norm, options, template, mesh, creases, noise):
    """The control mesh to start from, in the unit box: ``(V0, F, creases, template info)``."""
    found = None
    if template is None and mesh is not None and options.features == "auto":
        from mi_loop.fitting.template import feature_template

        found = feature_template(mesh[0], mesh[1], options.n_vertices)    # in the data's units: the decimation
    if found is not None:                 # is not scale-invariant (the fandisk normalised got 252 creases, not 266)
        V0, F, creases, tinfo = found     # sharp features: a planar-quadric template with creases along them
        # the fold barrier's averaged reference normals fight sharp edges (fandisk: NAE 0.77 -> 1.89 with it)
        tinfo = {"source": "mesh with sharp features", **tinfo, "fold": "off: the creases hold the features"}
        return norm.forward(V0), F, creases, tinfo
    if template is None:
        from mi_loop.fitting.template import make_template

        V0, F, tinfo = make_template(Pn, N, options.n_vertices, seed=options.seed, depth=options.template_depth,
                                     genus=options.template_genus, **template_options(noise["ratio"]))
        return V0, F, None, tinfo
    V0, F, _ = validate_mesh(template[0], template[1], "fit")
    return norm.forward(V0), F, creases, {"source": "user"}


def _operators(F, n, creases, options, fold):
    """The limit operators of the distance terms and (with ``fold``) of the barrier's denser samples, and the
    crossing test of ``options.no_crossing`` (or None)."""
    from mi_loop.ad.operator import LimitOperator

    fid, uv = sample_parameters(F, n, options.samples, options.seed)
    op = LimitOperator(F, n, fid, uv, creases=creases, derivatives=False)
    fold_op = None
    if fold > 0:      # the barrier's samples: denser than the distance terms', so small folds show
        fid_f, uv_f, _ = tessellate(F, FOLD_LEVEL)
        fold_op = LimitOperator(F, n, fid_f, uv_f, creases=creases, derivatives=True)
    crossings = None
    if options.no_crossing:
        from mi_loop.fitting.guard import CrossingTest

        crossings = CrossingTest(F, n, creases=creases)
    return op, fold_op, crossings


def _select(Pn, N, F, creases, options, fit_with, progress):
    """The ARAP weight whose fit to nine tenths of the points lies closest to the other tenth; ``(alpha, tried)``."""
    from mi_loop.energies.coverage import Coverage
    from mi_loop.energies.imls import IMLS

    held = held_out_split(len(Pn), options.seed)
    imls = IMLS(Pn[~held], N[~held], h0=options.h0)
    energies = (imls, Coverage(Pn[~held], N[~held], tree=imls.tree) if options.cover > 0 else None)

    def held_out_error(V):
        return surface_distances(*limit_mesh(V, F, SELECTION_LEVEL, creases=creases)[:2], Pn[held]).mean()

    # one bar for the candidates and the final fit: the candidates' share, then the final fit's
    step = None if progress is None else (lambda i, n, E: progress(i, n + n // len(ALPHAS), E))
    alpha, _, tried = select_alpha(lambda a, s: fit_with(energies, a, s), held_out_error, progress=step)
    return alpha, {**tried, "held_out_points": int(held.sum())}


def _check_template(template):
    if template is not None and not (isinstance(template, (tuple, list)) and len(template) == 2):
        raise ValueError("fit(): expected template to be a pair (V, F) of control points and faces, got "
                         f"{type(template).__name__}")


def _minimise(ops, energies, arap, V0, alpha: float, fold: float, options: FitOptions, progress):
    """One run of the loop from ``V0`` (unit box); ``(V, history, converged)`` with ``V`` the best iterate."""
    import mitsuba as mi

    from mi_loop.fitting import terms
    from mi_loop.fitting.loop import Parameter, optimise
    from mi_loop.fitting.optimisers import Adam, Constant
    from mi_loop.fitting.rules import Convergence, Failure, Refresh, Seeds

    op, fold_op, crossings = ops
    imls, coverage = energies
    x0 = mi.Float(V0.ravel().astype(np.float32))
    imls.update(np.array(op.positions(x0), dtype=np.float64).T)
    failure = Failure("fit", recoveries=5, hint="try a smaller --alpha or another template")
    e0 = float(imls.energy(op.positions(x0), reduce="mean")[0])
    if not np.isfinite(e0):
        raise failure.error(0, {"imls": e0})
    lr = float(np.clip(np.sqrt(e0) / 3.0, 1e-6, 0.05 * mean_edge_length(V0, arap.F)))
    parts = [terms.Distance(imls, op)]
    if coverage is not None:
        parts.append(terms.Coverage(coverage, op, options.cover))
    parts.append(terms.Rigidity(arap, alpha / len(V0)))
    if fold > 0:
        parts.append(terms.Fold(fold_op, fold, data=(imls.tree, imls.normals, FOLD_NEIGHBOURS), cosine=FOLD_COSINE))
    guard = None
    if crossings is not None:        # no step folds a control triangle or crosses the surface anew
        from mi_loop.fitting.guard import FoldGuard

        guard = FoldGuard(op, arap.F, V0, crossings=crossings)
    result = optimise({"x": Parameter(x0, Adam(), Constant(lr), guard=guard)}, parts, iterations=options.iterations,
                      seeds=Seeds(options.seed), refresh=Refresh(20, 0.25 * imls.h0, op),
                      convergence=Convergence(options.tolerance, patience=12, halvings=3, window=40),
                      failure=failure,
                      keep="best", progress=progress)
    history = {k: result.history.get(k, [0.0] * result.iterations) for k in ("imls", "cover", "arap", "fold")}
    history |= {"total": result.history["total"], "lr": result.history["lr"]}
    return result.values["x"], history, result.converged
