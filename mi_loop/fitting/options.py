"""The options of the fitting loops: one vocabulary, one default each, checked on construction.

- :class:`FitOptions`: the static fit (:func:`mi_loop.fitting.static.fit`, ``mi-loop fit``);
- :class:`SequenceOptions`: the frame-by-frame fit (:func:`mi_loop.fitting.sequence.fit_frame`,
  ``mi-loop fit-sequence``);
- :class:`ImageFitOptions`: shape and albedo from photos (:func:`mi_loop.fitting.images.fit_images`,
  ``mi-loop fit-images``).

Every default lives here once: :func:`~mi_loop.fitting.static.fit`'s keyword
arguments and the command line's defaults are read from these classes. A
rejected value raises :class:`OptionError` (a :class:`ValueError`) whose
message reads ``FitOptions(): expected alpha to be a finite number >= 0, got -1.0``;
it also carries the field, so the command line can name its flag instead.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from mi_loop.errors import expected
from mi_loop.render.multiview import IMAGE_MODES, LOSSES

__all__ = [
    "COVER",
    "IMAGE_INITS",
    "N_VERTICES",
    "SAMPLES",
    "SAMPLE_MODES",
    "FitOptions",
    "ImageFitOptions",
    "OptionError",
    "SequenceOptions",
]

#: Limit samples of the geometric terms: one per control vertex, a level-1 tessellation, random.
SAMPLE_MODES = ("vertices", "level1", "random")

#: Defaults shared by both loops (one place each).
N_VERTICES = 1000     # control vertices of the automatic template
SAMPLES = "level1"    # the points of a level-1 tessellation: about 4x the control vertices
COVER = 3.0           # weight of the coverage term (data points pull their nearest samples)
FOLD = 0.01           # weight of the static fit's fold barrier (limit normals against the data's)


class OptionError(ValueError):
    """A rejected option value.

    Parameters
    ----------
    owner : str
        The class or function that rejects it (``'FitOptions'``, ``'fit'``).
    name : str
        The field.
    what : str
        What the value should have been (``'a finite number >= 0'``).
    got : object
        The value.
    """

    def __init__(self, owner: str, name: str, what: str, got):
        self.owner, self.name, self.what, self.got = owner, name, what, got
        super().__init__(expected(owner, f"{name} to be {what}", self.shown))

    @property
    def shown(self):
        """The value as the message shows it (strings quoted), for :func:`mi_loop.errors.expected`."""
        return repr(self.got) if isinstance(self.got, str) else self.got

    def renamed(self, owner: str) -> OptionError:
        """The same error, reported by ``owner`` (a public function that built the options)."""
        return OptionError(owner, self.name, self.what, self.got)


def _is_int(value) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def _is_real(value) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def _check(options, rules: dict) -> None:
    """Check every field named in ``rules``: ``name -> (predicate, description)``."""
    owner = type(options).__name__
    for name, (ok, what) in rules.items():
        value = getattr(options, name)
        if not ok(value):
            raise OptionError(owner, name, what, value)


def _weight(value) -> bool:
    return _is_real(value) and math.isfinite(value) and value >= 0


def _positive_real(value) -> bool:
    return _is_real(value) and math.isfinite(value) and value > 0


def _count(value) -> bool:
    return _is_int(value) and value >= 1


def _seed(value) -> bool:
    return _is_int(value) and value >= 0


def _flag(value) -> bool:
    return isinstance(value, (bool, np.bool_))


WEIGHT = (_weight, "a finite number >= 0")
COUNT = (_count, "an integer >= 1")
SEED = (_seed, "an integer >= 0")
FLAG = (_flag, "True or False")
N_VERTICES_RULE = (lambda v: _is_int(v) and v >= 4, "an integer >= 4")
SAMPLES_RULE = (lambda v: v in SAMPLE_MODES, f"one of {SAMPLE_MODES}")
FEATURES_RULE = (lambda v: v in ("auto", "off"), "'auto' or 'off'")


@dataclass
class FitOptions:
    """Parameters of the static fit :func:`mi_loop.fitting.static.fit` (``mi-loop fit``).

    Attributes
    ----------
    n_vertices : int
        Control vertices of the automatic template (ignored with a template), >= 4.
    alpha : float or None
        ARAP weight in ``E = mean f^2 + cover E_cover + alpha E_arap / n``;
        None (default): 0.001 on clean data (the closest fits on the bunny and
        fandisk benchmarks), and on noisy data the best of 0.001 ... 1 on
        points held out of the fit (:mod:`mi_loop.fitting.noise`,
        :mod:`mi_loop.fitting.selection`).
    h0 : float or None
        IMLS support radius in the unit box; None: from the point spacing.
    samples : {'vertices', 'level1', 'random'}
        Limit samples of the distance terms: one per control vertex (the
        thesis's default, faster), the points of a level-1 tessellation
        (about 4x the control vertices: closer fits), or four uniformly
        random points per face (drawn once with ``seed``).
    iterations : int
        Iteration cap; the loop normally stops earlier on relative improvement.
    tolerance : float
        Relative improvement of the best energy below which the step halves
        (after 12 iterations without it) and the loop stops (over 40
        iterations, or after three halvings).
    cover : float
        Weight of the coverage term (:mod:`mi_loop.energies.coverage`); 0: off.
    seed : int
        Seed of the template's sampling and of ``samples='random'``.
    fold : float
        Weight of the fold barrier (:mod:`mi_loop.energies.fold`) on limit
        normals turned by more than 60 degrees from those of the nearest data
        points; 0: off. On dragon_20k at 1000 control vertices 0.01 removes the
        fold and the self-intersections; 0.1 and 1 fit worse (BENCHMARKS.md).
    features : {'auto', 'off'}
        For a mesh input: ``'auto'`` finds sharp feature curves (dihedral
        angle above 40 degrees, chains of at least 5 % of the diagonal) and,
        when there are any, fits a template decimated along them with
        infinitely sharp creases there (:func:`~mi_loop.fitting.template.feature_template`);
        ``'off'``: the smooth pipeline. Point clouds have no features here.
    """

    n_vertices: int = N_VERTICES
    alpha: float | None = None
    h0: float | None = None
    samples: str = SAMPLES
    iterations: int = 400
    tolerance: float = 5e-3
    cover: float = COVER
    seed: int = 0
    fold: float = FOLD
    features: str = "auto"

    def __post_init__(self):
        _check(self, {"n_vertices": N_VERTICES_RULE, "alpha": (lambda v: v is None or _weight(v), WEIGHT[1]),
                      "fold": WEIGHT,
                      "h0": (lambda v: v is None or _positive_real(v), "a finite number > 0 (or None: automatic)"),
                      "samples": SAMPLES_RULE, "iterations": COUNT, "tolerance": WEIGHT,
                      "cover": WEIGHT, "seed": SEED, "features": FEATURES_RULE})

    @property
    def terms(self) -> list:
        """Names of the energy terms that are on, largest weight first where it is fixed."""
        arap = self.alpha is None or self.alpha > 0
        return (["IMLS"] + (["coverage"] if self.cover > 0 else []) + (["ARAP"] if arap else [])
                + (["fold"] if self.fold > 0 else []))


@dataclass
class SequenceOptions:
    """Parameters of :func:`mi_loop.fitting.sequence.fit_frame` and ``mi-loop fit-sequence``.

    Defaults tuned on 2 CPU cores. Stored in ``sequence.json`` by
    ``fit-sequence``, so that ``--resume`` continues with the same ones.

    Attributes
    ----------
    alpha : float
        ARAP weight (relative to the previous frame's fit).
    alpha_rest : float
        ARAP weight relative to the template (frame 0's start): keeps the cage
        from drifting into folds over a long sequence; 0: off.
    fold : float
        Weight of the barrier on limit-sample normals that turned by more than
        60 degrees since the previous frame (folds); 0: off.
    beta : float
        Image weight, relative to the geometric gradient (the image gradient is
        scaled to its RMS at each frame's first render; see
        :mod:`mi_loop.fitting.sequence`).
    seen : float
        Image weight where the data supports the surface, relative to where it
        does not (in [0, 1]): images hold what depth never saw and do not pull
        accurate geometry off. For mesh frames it is scaled by
        ``min(1, (2 sigma / p)^2)``, the mesh's roughness against the pixel
        width at the subject (see :mod:`mi_loop.fitting.sequence`).
    lam : float
        ``lambda`` of the ``(I + lambda L)^-1`` smoothing of the image gradient (0: off).
    reach : int
        IMLS reaches ``h0 2^reach`` from a sample (``max_growths``); farther
        samples are not pulled (a side the depth cameras never saw).
    views : int
        Cameras in the rig (mesh frames without photos).
    views_per_iteration : int
        Views rendered per image refresh, in ``[1, views]`` (a seeded sweep of all views).
    image_every : int
        Iterations between image refreshes (the latest image gradient is added to every step).
    resolution, spp, target_spp : int
        Image size of the rig (photos keep theirs); samples per pixel of the
        differentiable and of the target renders.
    level : int
        Tessellation level (0..6) of the rendered limit surface.
    loss : {'l1', 'l2'}
    mode : {'shading', 'silhouette'}
        Of the rig's renders (photos are compared as they are).
    geometric, image : bool
        IMLS + coverage terms (False: image only, ARAP kept); the image term.
    iterations : int
        Iterations per frame (the first half with stiff ARAP).
    first_iterations : int
        Iterations of the first frame (from the template).
    stiff_factor : float
        ARAP weight factor for the first half of the iterations.
    cover : float
        Weight of the coverage term.
    albedo_lr : float
        Adam step of the per-control-vertex albedo on the first frame (photos only).
    albedo_refine : float
        Albedo step of the later frames relative to ``albedo_lr`` (0: kept from the first frame).
    seed : int
        Seed of the views, the frame samples and the automatic template.
    n_vertices : int
        Control vertices of the automatic template (>= 4).
    samples : {'vertices', 'level1', 'random'}
        Limit samples of the geometric terms.
    n_points : int
        Points sampled on every mesh frame.
    poisson_template : bool
        Build the automatic template by screened Poisson even from a mesh frame.
    deterministic : bool
        Bit-reproducible image term: the reverse render runs on one thread (slower).
    """

    alpha: float = 0.01
    alpha_rest: float = 0.01
    fold: float = 1.0
    beta: float = 10.0
    seen: float = 0.1
    lam: float = 10.0
    reach: int = 2
    views: int = 20
    views_per_iteration: int = 2
    image_every: int = 6
    resolution: int = 96
    spp: int = 4
    target_spp: int = 32
    level: int = 1
    loss: str = "l1"
    mode: str = "shading"
    geometric: bool = True
    image: bool = True
    iterations: int = 200
    first_iterations: int = 400
    stiff_factor: float = 100.0
    cover: float = COVER
    albedo_lr: float = 0.02
    albedo_refine: float = 0.1
    seed: int = 0
    n_vertices: int = N_VERTICES
    samples: str = SAMPLES
    n_points: int = 20_000
    poisson_template: bool = False
    deterministic: bool = False

    def __post_init__(self):
        _check(self, {"alpha": WEIGHT, "alpha_rest": WEIGHT, "fold": WEIGHT, "beta": WEIGHT,
                      "lam": WEIGHT, "cover": WEIGHT,
                      "stiff_factor": WEIGHT, "albedo_lr": WEIGHT, "albedo_refine": WEIGHT,
                      "seen": (lambda v: _is_real(v) and 0 <= v <= 1, "a number in [0, 1]"),
                      "reach": (lambda v: _is_int(v) and 0 <= v <= 10, "an integer in 0..10"),
                      "image_every": COUNT, "first_iterations": COUNT, "views": COUNT,
                      "resolution": COUNT, "spp": COUNT, "target_spp": COUNT,
                      "level": (lambda v: _is_int(v) and 0 <= v <= 6, "an integer in 0..6"),
                      "loss": (lambda v: v in LOSSES, f"one of {LOSSES}"),
                      "mode": (lambda v: v in IMAGE_MODES, f"one of {IMAGE_MODES}"),
                      "geometric": FLAG, "image": FLAG, "poisson_template": FLAG, "deterministic": FLAG,
                      "iterations": COUNT, "seed": SEED,
                      "n_vertices": N_VERTICES_RULE, "samples": SAMPLES_RULE, "n_points": COUNT})
        if not (_is_int(self.views_per_iteration) and 1 <= self.views_per_iteration <= self.views):
            raise OptionError("SequenceOptions", "views_per_iteration",
                              f"an integer in [1, views={self.views}]", self.views_per_iteration)
        if not (self.geometric or self.image):
            raise OptionError("SequenceOptions", "geometric or image", "True (both terms are off: "
                              "nothing to fit)", False)

    #: Fields of older versions, ignored when read back (the image term no longer ends the frame).
    RETIRED = ("joint_iterations", "joint_lr_scale")
    #: Fields of older versions under their current names.
    RENAMED = {"geo_iterations": "iterations", "image_smooth": "lam"}

    @classmethod
    def from_dict(cls, values: dict) -> SequenceOptions:
        """Options from :func:`dataclasses.asdict` output; older files' missing fields get their defaults.

        Retired fields (:attr:`RETIRED`) are dropped, renamed ones (:attr:`RENAMED`) read
        under their current names; any other unknown key is an error.
        """
        names = {f.name for f in fields(cls)}
        values = {cls.RENAMED.get(k, k): v for k, v in values.items() if k not in cls.RETIRED}
        unknown = sorted(set(values) - names)
        if unknown:
            raise OptionError("SequenceOptions", "every key", f"one of the fields {sorted(names)}", unknown)
        return cls(**values)

    @property
    def rig(self):
        """The :class:`~mi_loop.render.multiview.RigOptions` of the image term."""
        from mi_loop.render.multiview import RigOptions

        return RigOptions(views=self.views, resolution=self.resolution, spp=self.spp,
                          target_spp=self.target_spp, level=self.level, loss=self.loss, mode=self.mode,
                          deterministic=self.deterministic)


#: Starting shapes of :func:`mi_loop.fitting.images.fit_images` (a mesh is given as arrays instead).
IMAGE_INITS = ("hull", "sphere")


@dataclass
class ImageFitOptions:
    """Parameters of :func:`mi_loop.fitting.images.fit_images` and ``mi-loop fit-images``.

    Attributes
    ----------
    n_vertices : int
        Most control vertices: the start mesh is chosen so that ``refinements``
        exact Loop steps stay at or below it (>= 4).
    init : {'hull', 'sphere'}
        Start shape: a template of the visual hull of the masks (screened
        Poisson of the hull's boundary, decimated), or an icosphere in the
        hull's box (ignored when a start mesh is given).
    refinements : int
        Exact Loop refinements of the control mesh (stages - 1), >= 0.
    resolution : int or None
        Longest image side at the finest stage (the photos' own if None or
        larger); each coarser stage halves it.
    spp : int
        Samples per pixel of the differentiable renders.
    iterations : int
        Most iterations in all (split evenly between the stages; a stage ends
        earlier when its loss stalls).
    views_per_iteration : int
        Photos rendered per iteration (a seeded sweep through all of them).
    lr : float
        Step of the smooth parameterisation, relative to the hull's box diagonal.
    lr_decay : float
        Step at the end of each stage relative to its start (exponential decay), in (0, 1].
    albedo_lr : float
        Adam step of the albedo; 0: kept at ``albedo`` (``--fixed-albedo``).
    lam : float
        ``lambda`` of the ``(I + lambda L)`` parameterisation (:mod:`mi_loop.fitting.largesteps`).
    laplacian : float
        Weight of the cage's uniform-Laplacian term ``|L x|^2 / (n d^2)`` (``d`` the
        box diagonal), which keeps control vertices spread; 0: off.
    albedo : float
        Start albedo (grey) in [0, 1].
    tolerance : float
        A stage ends early (after half its iterations) when the mean loss over
        two sweeps of the photos falls by less than this fraction of the best
        earlier two-sweep mean; 0: never.
    triangles : int
        Rendered triangles per stage, roughly (sets the tessellation level).
    integrator : {'direct_projective', 'prb_projective'}
    seed : int
        Seed of the view order and of the renders.
    deterministic : bool
        Bit-reproducible runs: reverse renders on one thread (slower).
    """

    n_vertices: int = 900
    init: str = "hull"
    refinements: int = 1
    resolution: int | None = None
    spp: int = 4
    iterations: int = 300
    views_per_iteration: int = 2
    lr: float = 0.01
    lr_decay: float = 1.0
    albedo_lr: float = 0.02
    lam: float = 20.0
    laplacian: float = 0.05
    albedo: float = 0.5
    tolerance: float = 0.005
    triangles: int = 20_000
    integrator: str = "direct_projective"
    seed: int = 0
    deterministic: bool = False

    def __post_init__(self):
        from mi_loop.render.photo import INTEGRATORS

        _check(self, {"n_vertices": N_VERTICES_RULE,
                      "init": (lambda v: v in IMAGE_INITS, f"one of {IMAGE_INITS}"),
                      "refinements": (lambda v: _is_int(v) and 0 <= v <= 4, "an integer in 0..4"),
                      "resolution": (lambda v: v is None or (_is_int(v) and v >= 16),
                                     "an integer >= 16 (or None: the photos' size)"),
                      "spp": COUNT, "iterations": COUNT, "views_per_iteration": COUNT,
                      "lr": (_positive_real, "a finite number > 0"),
                      "albedo_lr": WEIGHT,
                      "lr_decay": (lambda v: _is_real(v) and 0 < v <= 1, "a number in (0, 1]"),
                      "lam": WEIGHT, "laplacian": WEIGHT,
                      "albedo": (lambda v: _is_real(v) and 0 <= v <= 1, "a number in [0, 1]"),
                      "tolerance": WEIGHT, "triangles": COUNT,
                      "integrator": (lambda v: v in INTEGRATORS, f"one of {INTEGRATORS}"),
                      "seed": SEED, "deterministic": FLAG})
