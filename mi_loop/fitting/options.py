"""The options of the fitting loops: one vocabulary, one declaration per option, checked on construction.

- :class:`FitOptions`: the static fit (:func:`mi_loop.fitting.static.fit`, ``mi-loop fit``);
- :class:`SequenceOptions`: the frame-by-frame fit (:func:`mi_loop.fitting.sequence.fit_frame`,
  ``mi-loop fit-sequence``);
- :class:`ImageFitOptions`: shape and albedo from photos (:func:`mi_loop.fitting.images.fit_images`,
  ``mi-loop fit-images``).

Every field is declared once, by :func:`~mi_loop.fitting.declarations.option`:
its default, the rule its values obey (which also says how the command line
reads one), its help text and, where they are not the plain ``--`` + name with
dashes, its flag, metavar, deprecated spellings and special command-line forms
(:mod:`mi_loop.fitting.declarations`).
:func:`~mi_loop.fitting.static.fit`'s defaults, ``__post_init__``'s checks and
the whole ``mi-loop`` parser of these options (:mod:`mi_loop.app.parser`) are read
from there. A rejected value raises :class:`~mi_loop.fitting.declarations.OptionError` (a :class:`ValueError`)
whose message reads ``FitOptions(): expected alpha to be a finite number >= 0, got -1.0``;
it also carries the field, so the command line can name its flag instead.
"""
from __future__ import annotations

from dataclasses import dataclass, fields

from mi_loop.fitting.declarations import (
    COUNT,
    FLAG,
    POSITIVE,
    SEED,
    WEIGHT,
    OptionError,
    Rule,
    at_least,
    check_fields,
    integers,
    interval,
    one_of,
    option,
)
from mi_loop.render.images import INTEGRATORS, LOSSES
from mi_loop.render.scene import RIG_MODES

__all__ = ["ALPHA_REST", "COVER", "FOLD", "IMAGE_INITS", "LIGHTINGS", "N_VERTICES", "PHOTOS_ALPHA_REST", "POINTS_COVER",
           "POINTS_FOLD", "SAMPLES", "SAMPLE_MODES", "SOLVERS", "FitOptions", "ImageFitOptions", "SequenceOptions"]

#: Limit samples of the geometric terms: one per control vertex, a level-1 tessellation, random.
SAMPLE_MODES = ("vertices", "level1", "random")
#: Starting shapes of :func:`mi_loop.fitting.images.fit_images` (a mesh is given as arrays instead).
IMAGE_INITS = ("hull", "sphere")
#: How the photos' surface is lit: by the emitters given, or by a lighting estimated (:mod:`mi_loop.render.lighting`).
LIGHTINGS = ("given", "sh")
#: Frame solvers of fit-sequence (:mod:`mi_loop.fitting.optimisers`).
SOLVERS = ("gauss-newton", "adam")
LIGHTING_HELP = ("light the surface with the --emitters (given, default) or estimate the lighting: spherical "
                 "harmonics of bands 0-2 (sh)")
EXPOSURE_HELP = "with --lighting sh, no RGB gain per photo (exposure and white balance are estimated by default)"
LIGHT_LR_HELP = "Adam step of the estimated lighting and gains (default %(default)s)"

#: Defaults shared by both loops (one place each).
N_VERTICES = 1000     # control vertices of the automatic template
SAMPLES = "level1"    # the points of a level-1 tessellation: about 4x the control vertices
COVER = 3.0           # weight of the coverage term (data points pull their nearest samples)
#: fit-sequence's coverage weight on point-cloud frames without photos (mesh frames and photos keep :data:`COVER`).
#: On D-FAUST the pulls of 100,000 points crease the shoulders: 0.37 % of the area flipped at frame 0 against
#: 0.06 % at 0.3, the surface 1 % farther (later frames up to 40 % farther, where 3 creases its way closer). The
#: clean fox's mesh frames need 3 (21/24 frames within target against 8/24), and so do the captures' depth with
#: photos (without ``--track`` the spot capture's last mean is 65 % larger at 0.3).
POINTS_COVER = 0.3
FOLD = 0.01           # weight of the fold barrier: the static fit's, and fit-sequence's on mesh frames
#: fit-sequence's fold-barrier weight on point-cloud frames (against the previous frame's limit normals). On
#: mesh frames, whose normals are exact, :data:`FOLD`: 1 there held the clean fox's swinging legs back
#: (21/24 frames within target, flipped up to 1.8 %, against 24/24 and 0.9 % at 0.01).
POINTS_FOLD = 1.0
ALPHA_REST = 0.01     # fit-sequence's ARAP weight relative to the template
#: fit-sequence's ARAP weight relative to the template on frames whose image term fits photos. Partial depth never
#: sees one side; only the photos do, and the template holds it. On ``spot_fine`` (``--track 10``, the key rays; two
#: runs each) 0.1 took the last frame's drift from 0.49-0.52 % to 0.38-0.40 %, the largest flipped area from 0.52-0.56 %
#: to 0.009-0.027 %, the last mean from 0.0021-0.0022 to 0.0016 against :data:`ALPHA_REST`; 0.3 lowered the drift a
#: further 7 % frame by frame on spot_fine and the smooth spot and the fox's flipped area by 38 % (BENCHMARKS.md).
PHOTOS_ALPHA_REST = 0.3
#: ``--holdout K``: 0 (off) or every K-th photo, K >= 2 (K = 1 would leave nothing to fit).
HOLDOUT = Rule(lambda v: SEED.ok(v) and v != 1, "0 (off) or an integer >= 2", int)


# -- help texts that several fields share ----------------------------------------------

SAMPLES_HELP = ("limit samples of the distance terms: 'level1' (default) the points of a level-1 "
                "tessellation, about 4 per control vertex (closer fits); 'vertices' one per control vertex "
                "(its limit point: faster, the thesis's choice); 'random' four uniformly random points per "
                "control face, drawn once from --seed")
SEED_HELP = "random seed: of {} (default %(default)s); {}the same seed, input and thread count give the same result"
COVER_HELP = "weight of the coverage term: data points pull their nearest limit samples (default %(default)s; 0: off)"
TEMPLATE_HELP = "control vertices of the automatic template (default %(default)s)"
SPP_HELP = "samples per pixel of the differentiable renders (default %(default)s)"
TEMPLATE_DEPTH = integers(4, 10).or_none("from --vertices")
TEMPLATE_DEPTH_HELP = ("octree depth of the automatic template's screened Poisson (default: 6 up to 2000 --vertices, "
                       "7 up to 8000, 8 above{}; a dense scan of a body whose arms lie close to the torso needs 8: "
                       "6 webs the armpits)")
TEMPLATE_GENUS = at_least(0).or_none("as built")
TEMPLATE_GENUS_HELP = ("the subject's genus (a body: 0): the automatic template's shortest handle loops are cut and "
                       "capped until it has this many, where a fine --template-depth joins parts that touch "
                       "(default: as built)")
NO_CROSSING_HELP = ("keep the limit surface from passing through itself: every step is tested for crossing triangles "
                    "of a level-2 tessellation, and the control points that would make new ones stay where they "
                    "were (slower; for parts that come close, such as arms against a body)")


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
        iterations, or after three halvings); 0: the loop runs all its
        iterations at the first step size (:class:`~mi_loop.fitting.rules.Convergence`:
        one meaning of 0 in the three fits).
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
    template_depth : int or None
        Octree depth of the automatic template's screened Poisson (4 to 10); None (default): from
        ``n_vertices`` (:func:`mi_loop.fitting.template.poisson_depth`).
    template_genus : int or None
        The subject's genus: the automatic template's shortest handle loops are cut until it has
        this many (:func:`mi_loop.mesh.handles.cut_handles`); None (default): as built.
    no_crossing : bool
        Pass every step through the fold guard (:class:`~mi_loop.fitting.guard.FoldGuard`) with a
        crossing test (:class:`~mi_loop.fitting.guard.CrossingTest`): no step turns a control triangle
        over or makes the limit surface pass through itself where it did not.
    """

    n_vertices: int = option(N_VERTICES, rule=at_least(4), help=TEMPLATE_HELP, flag="--vertices", metavar="N",
                             exclusive="template")
    alpha: float | None = option(None, rule=WEIGHT.or_none(),
                                 help="ARAP weight (default: 0.001 on clean data; on noisy data the best of 0.001, "
                                      "0.01, 0.1, 1 on a tenth of the points held out of the fit)")
    h0: float | None = option(None, rule=POSITIVE.or_none("automatic"),
                              help="IMLS radius in the unit box (default: from the point spacing)")
    samples: str = option(SAMPLES, rule=one_of(SAMPLE_MODES), help=SAMPLES_HELP)
    iterations: int = option(400, rule=COUNT, metavar="N",
                             help="most iterations of the fit; it stops earlier when --tolerance says it has "
                                  "converged (default %(default)s)")
    tolerance: float = option(5e-3, rule=WEIGHT,
                              help="relative improvement of the best energy below which the step halves and the "
                                   "fit stops before --iterations (default %(default)s; 0: it runs all of them)")
    cover: float = option(COVER, rule=WEIGHT, help=COVER_HELP)
    seed: int = option(0, rule=SEED, help=SEED_HELP.format("the automatic template's sampling and of --samples "
                                                           "random", ""))
    fold: float = option(FOLD, rule=WEIGHT,
                         help="weight of the fold barrier on limit normals turned by more than 60 degrees from the "
                              "nearest data normals (default %(default)s; 0: off)")
    features: str = option("auto", rule=one_of(("auto", "off"), "'auto' or 'off'"),
                           help="for a mesh input, keep its sharp features (edges above 40 degrees) as creases of the "
                                "control mesh (default %(default)s; point clouds have none here)")
    template_depth: int | None = option(None, rule=TEMPLATE_DEPTH, metavar="D", help=TEMPLATE_DEPTH_HELP.format(""))
    template_genus: int | None = option(None, rule=TEMPLATE_GENUS, metavar="G", help=TEMPLATE_GENUS_HELP)
    no_crossing: bool = option(False, rule=FLAG, help=NO_CROSSING_HELP)

    def __post_init__(self):
        check_fields(self)

    @property
    def terms(self) -> list:
        """Names of the energy terms that are on, largest weight first where it is fixed."""
        arap = self.alpha is None or self.alpha > 0
        return (["IMLS"] + (["coverage"] if self.cover > 0 else []) + (["ARAP"] if arap else [])
                + (["fold"] if self.fold > 0 else []))


@dataclass
class SequenceOptions:
    """Parameters of :func:`mi_loop.fitting.sequence.fit_frame` and ``mi-loop fit-sequence``.

    Stored in ``sequence.json`` by ``fit-sequence``, so that ``--resume`` continues
    with the same ones.

    Attributes
    ----------
    alpha : float
        ARAP weight (relative to the previous frame's fit).
    alpha_rest : float or None
        ARAP weight relative to the template (frame 0's start): keeps the cage
        from drifting into folds over a long sequence; 0: off; None (default):
        :data:`PHOTOS_ALPHA_REST` where the image term fits photos, :data:`ALPHA_REST`
        else (:meth:`rest_weight`).
    fold : float or None
        Weight of the barrier on limit-sample normals that turned by more than
        60 degrees since the previous frame (folds); 0: off; None (default):
        :data:`FOLD` on mesh frames, :data:`POINTS_FOLD` on point clouds (:meth:`fold_weight`).
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
        Most iterations of each frame after the first (the first half with
        stiff ARAP); a frame stops earlier by ``tolerance``.
    first_iterations : int
        Iterations of the first frame (from the template).
    stiff_factor : float
        ARAP weight factor for the first half of the iterations.
    cover : float or None
        Weight of the coverage term; None (default): :data:`COVER` on mesh frames and with photos,
        :data:`POINTS_COVER` on point clouds without (:meth:`cover_weight`).
    albedo_lr : float
        Adam step of the per-control-vertex albedo on the first frame (photos only).
    albedo_refine : float
        Albedo step of the later frames relative to ``albedo_lr`` (0: kept from the first frame).
    lighting, exposure, light_lr :
        As in :class:`ImageFitOptions` (photos only): the lighting and the
        photos' gains are estimated on every frame, carried from frame to
        frame while the cameras stay.
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
    template_depth : int or None
        Octree depth of the automatic template's screened Poisson (4 to 10); None (default): from
        ``n_vertices`` (:func:`mi_loop.fitting.template.poisson_depth`). Given, a mesh frame's template
        is built by Poisson too. A dense scan of a body whose arms lie close to the torso needs 8: the
        default 6 webs the armpits.
    template_genus : int or None
        The subject's genus: the automatic template's shortest handle loops are cut until it has
        this many (:func:`mi_loop.mesh.handles.cut_handles`); None (default): as built.
    no_crossing : bool
        The fold guard of every step (and the coarse stage's step) also keeps the limit surface
        from passing through itself where it did not (:class:`~mi_loop.fitting.guard.CrossingTest`).
    deterministic : bool
        Bit-reproducible image term: the reverse render runs on one thread (slower).
    tolerance : float
        Relative improvement of the frame's energy below which a frame stops
        before ``iterations``; 0 (default): every frame runs all its iterations.
    flow : float
        With photos: weight of the optical-flow term (:mod:`mi_loop.fitting.flow`); 0: off.
    solver : {'gauss-newton', 'adam'}
        Frame solver: Gauss-Newton steps through the terms' curvature
        (:class:`~mi_loop.fitting.optimisers.GaussNewton`), or Adam.
    gn_iterations : int
        Gauss-Newton steps of each frame after the first (the first takes 3 times as many).
    track : int
        Before each frame's solve, carry the previous fit to the frame's points with an embedded
        deformation graph of about one node per ``track`` control vertices (:mod:`mi_loop.fitting.track`);
        0: off (the solve starts from the previous fit).
    tangential : float
        With ``track``: weight of the term that holds each control point to where the graph carried it,
        along the surface (:class:`~mi_loop.fitting.terms.Tangential`), on mesh frames; point-cloud frames
        hold :data:`~mi_loop.fitting.sequence.POINTS_HOLD` times as hard; 0: off.
    track_flow : float
        With ``track`` and photos: weight of the camera rays, through where the optical flow carried
        the previous fit's samples, that the graph holds them on (:func:`~mi_loop.fitting.flow.flow_rays`);
        0: off. Where the photos carry texture the rays cut the drift by a third; where the texture is too
        smooth for the flow to follow, they change nothing measurable.
    pinned_hold : float
        With the flow's rays: the tangential hold of a control point whose limit support the rays
        pinned, relative to one they did not (:func:`~mi_loop.fitting.track.pinned_hold`): what the
        photos pinned is held harder than what the graph alone carried; 1: the same.
    track_key : int
        With the flow's rays: also the rays of the flows from the photos of 2, 4, ... and ``K`` frames
        before (:func:`~mi_loop.app.sequence_frames.key_gaps`; each frame's fit carried to this one's
        photos), so that the flow's error is not chained through every frame; 0 or 1: off.
    """

    alpha: float = option(0.01, rule=WEIGHT, help="ARAP weight relative to the previous frame (default %(default)s)")
    alpha_rest: float | None = option(None, rule=WEIGHT.or_none(f"{ALPHA_REST:g}, or {PHOTOS_ALPHA_REST:g} with "
                                                                 f"--images"),
                                      help=f"ARAP weight relative to the template: against folds, and what holds "
                                           f"the side the depth does not see (default: {ALPHA_REST:g}, or "
                                           f"{PHOTOS_ALPHA_REST:g} with --images; 0: off)")
    fold: float | None = option(None, rule=WEIGHT.or_none(f"{FOLD:g} on mesh frames, {POINTS_FOLD:g} on point "
                                                          "clouds"),
                                help=f"weight of the fold barrier on limit normals turned by more than 60 degrees "
                                     f"since the previous frame (default: {FOLD:g} on mesh frames, {POINTS_FOLD:g} "
                                     f"on point clouds; 0: off)")
    beta: float = option(10.0, rule=WEIGHT,
                         help="image weight relative to the geometric gradient (default %(default)s)")
    seen: float = option(0.1, rule=interval(0, 1),
                         help="image weight where the data covers the surface, relative to where it does not "
                              "(default %(default)s)")
    lam: float = option(10.0, rule=WEIGHT, deprecated=("--image-smooth",),
                        help="lambda of the (I + lambda L)^-1 smoothing over the cage of the image gradient "
                             "(default %(default)s; 0: off)")
    reach: int = option(2, rule=integers(0, 10), metavar="REACH",
                        help="IMLS reaches h0 * 2^REACH from a sample; farther ones are not pulled "
                             "(default %(default)s)")
    views: int = option(20, rule=COUNT,
                        help="cameras around the subject for mesh frames without --images (default %(default)s)")
    views_per_iteration: int = option(2, rule=COUNT, metavar="K", capped_by="views",
                                      help="views rendered per image refresh, at most --views (default %(default)s, "
                                           "or --views if fewer)")
    image_every: int = option(6, rule=COUNT, metavar="N",
                              help="iterations between image refreshes; the latest image gradient is added to every "
                                   "step (default %(default)s)")
    resolution: int = option(96, rule=COUNT, flag="--res", metavar="R",
                             help="image width and height of the rendered rig, in pixels (default %(default)s; "
                                  "photos keep theirs)")
    spp: int = option(4, rule=COUNT, help=SPP_HELP)
    target_spp: int = option(32, rule=COUNT, help="samples per pixel of the rig's target renders (default %(default)s)")
    level: int = option(1, rule=integers(0, 6), metavar="L",
                        help="tessellation level of the rendered limit surface, 4**L triangles per control face "
                             "(default %(default)s)")
    loss: str = option("l1", rule=one_of(LOSSES),
                       help="pixel loss of the rendered rig: mean absolute (l1, default) or mean squared (l2) "
                            "difference between the render and the target render")
    mode: str = option("shading", rule=one_of(RIG_MODES),
                       help="images of the rendered rig: shaded (shading, default) or silhouettes only "
                            "(silhouette)")
    geometric: bool = option(True, rule=FLAG, flag="--image-only", exclusive="terms",
                             help="image term (+ ARAP) only, no IMLS or coverage (baseline)")
    image: bool = option(True, rule=FLAG, flag="--no-image", exclusive="terms",
                         help="geometric terms only (baseline)")
    iterations: int = option(200, rule=COUNT, metavar="N",
                             help="most iterations of each frame after the first; a frame stops earlier when "
                                  "--tolerance says it has converged (default %(default)s)")
    first_iterations: int = option(400, rule=COUNT, metavar="N",
                                   help="iterations of the first frame, from the template (default %(default)s)")
    stiff_factor: float = option(100.0, rule=WEIGHT,
                                 help="factor of the ARAP weights in the first half of a frame's iterations "
                                      "(default %(default)s)")
    cover: float | None = option(None, rule=WEIGHT.or_none(f"{COVER:g} on mesh frames and with --images, "
                                                            f"{POINTS_COVER:g} on point clouds without"),
                                 help=f"weight of the coverage term: data points pull their nearest limit samples "
                                      f"(default: {COVER:g} on mesh frames and with --images, {POINTS_COVER:g} on "
                                      f"point clouds without; 0: off)")
    albedo_lr: float = option(0.02, rule=WEIGHT,
                              help="Adam step of the per-control-vertex albedo on the first frame (with --images; "
                                   "default %(default)s; 0: not estimated)")
    albedo_refine: float = option(0.1, rule=WEIGHT,
                                  help="albedo step of later frames relative to --albedo-lr (default %(default)s; "
                                       "0: kept from the first frame)")
    lighting: str = option("given", rule=one_of(LIGHTINGS), help=LIGHTING_HELP)
    exposure: bool = option(True, rule=FLAG, flag="--no-exposure", help=EXPOSURE_HELP)
    light_lr: float = option(0.01, rule=WEIGHT, help=LIGHT_LR_HELP)
    seed: int = option(0, rule=SEED, help=SEED_HELP.format(
        "the automatic template's sampling and of --samples random, of the views and of the frames' samples",
        "with --no-image or --deterministic "))
    n_vertices: int = option(N_VERTICES, rule=at_least(4), help=TEMPLATE_HELP, flag="--vertices", metavar="N",
                             exclusive="template")
    samples: str = option(SAMPLES, rule=one_of(SAMPLE_MODES), help=SAMPLES_HELP)
    n_points: int = option(20_000, rule=COUNT, flag="--points", metavar="N",
                           help="points sampled on every mesh frame for the geometric terms (default %(default)s); "
                                "point-cloud frames are used as they are")
    poisson_template: bool = option(False, rule=FLAG, help="build the automatic template by screened Poisson even "
                                                           "when the first frame is a mesh")
    template_depth: int | None = option(None, rule=TEMPLATE_DEPTH, metavar="D",
                                        help=TEMPLATE_DEPTH_HELP.format("; given, a mesh frame's template is built by "
                                                                        "Poisson too"))
    template_genus: int | None = option(None, rule=TEMPLATE_GENUS, metavar="G", help=TEMPLATE_GENUS_HELP)
    no_crossing: bool = option(False, rule=FLAG, help=NO_CROSSING_HELP)
    deterministic: bool = option(False, rule=FLAG, help="bit-reproducible image term: the reverse render runs on "
                                                        "one thread (slower)")
    tolerance: float = option(0.0, rule=WEIGHT,
                              help="relative improvement of the frame's energy below which a frame stops before "
                                   "--iterations (default %(default)s: every frame runs all its iterations)")
    flow: float = option(0.0, rule=WEIGHT,
                         help="with --images: weight of the optical-flow term, which pulls the limit surface's "
                              "samples onto the pixels the flow between a camera's photos of consecutive frames "
                              "carried them to (default %(default)s: off)")
    solver: str = option("adam", rule=one_of(SOLVERS),
                         help="frame solver: Gauss-Newton steps through the terms' curvature (gauss-newton), or "
                              "Adam (adam, default)")
    gn_iterations: int = option(12, rule=COUNT, metavar="N",
                                help="Gauss-Newton steps of each frame after the first (default %(default)s; the "
                                     "first frame takes 3 times as many)")
    track: int = option(0, rule=at_least(0), metavar="K",
                        help="before each frame's solve, carry the previous fit to the frame's points with an "
                             "embedded deformation graph, one node per about K control vertices (default "
                             "%(default)s: off)")
    tangential: float = option(1.0, rule=WEIGHT, metavar="W",
                               help="with --track: weight of the term that holds each control point, along the "
                                    "surface, where the graph carried it, on mesh frames; point clouds hold 3 times "
                                    "as hard (default %(default)s; 0: off)")
    track_flow: float = option(1.0, rule=WEIGHT, metavar="W",
                               help="with --track and --images: weight of the camera rays that the graph holds the "
                                    "surface's material points on, through where the optical flow between a camera's "
                                    "photos of consecutive frames carried them (default %(default)s; 0: off)")
    pinned_hold: float = option(10.0, rule=WEIGHT, metavar="K",
                                help="with the flow's rays (--track-flow): hold the control points that the rays "
                                     "pinned K times as hard along the surface as --tangential (default "
                                     "%(default)s; 1: the same)")
    track_key: int = option(8, rule=at_least(0), metavar="K",
                            help="with the flow's rays (--track-flow): also the rays of the optical flow from the "
                                 "photos of 2, 4, ... and K frames before (the powers of two below K, then K), "
                                 "where those frames' fits saw the material (default %(default)s; 0 or 1: off)")

    def __post_init__(self):
        check_fields(self)
        if self.views_per_iteration > self.views:
            raise OptionError("SequenceOptions", "views_per_iteration",
                              f"an integer in [1, views={self.views}]", self.views_per_iteration)
        if not (self.geometric or self.image):
            raise OptionError("SequenceOptions", "geometric or image", "True (both terms are off: "
                              "nothing to fit)", False)

    def frame_iterations(self, first: bool) -> int:
        """Most iterations of a frame for the solver: the first frame's (``first``) or a later one's.

        Parameters
        ----------
        first : bool
            The first frame (from the template).
        """
        if self.solver == "gauss-newton":
            return 3 * self.gn_iterations if first else self.gn_iterations
        return self.first_iterations if first else self.iterations

    def cover_weight(self, mesh_frame: bool, photos: bool = False) -> float:
        """A frame's coverage weight: ``cover``, or by default :data:`COVER` on a mesh frame or with photos,
        :data:`POINTS_COVER` on a point cloud without.

        Parameters
        ----------
        mesh_frame : bool
            The frame is a mesh (its samples cover the whole surface, with exact normals).
        photos : bool
            The frame's image term fits photos.
        """
        if self.cover is not None:
            return self.cover
        return COVER if mesh_frame or photos else POINTS_COVER

    def rest_weight(self, photos: bool) -> float:
        """A frame's ARAP weight relative to the template: ``alpha_rest``, or by default :data:`PHOTOS_ALPHA_REST`
        where the image term fits photos, :data:`ALPHA_REST` else.

        Parameters
        ----------
        photos : bool
            The frame's image term fits photos.

        Examples
        --------
        >>> SequenceOptions().rest_weight(photos=True), SequenceOptions().rest_weight(photos=False)
        (0.3, 0.01)
        >>> SequenceOptions(alpha_rest=0).rest_weight(photos=True)
        0
        """
        if self.alpha_rest is not None:
            return self.alpha_rest
        return PHOTOS_ALPHA_REST if photos else ALPHA_REST

    def fold_weight(self, mesh_frame: bool) -> float:
        """The fold-barrier weight of a frame: ``fold``, or :data:`FOLD` on a mesh frame, :data:`POINTS_FOLD` else.

        Parameters
        ----------
        mesh_frame : bool
            The frame is a mesh.
        """
        if self.fold is not None:
            return self.fold
        return FOLD if mesh_frame else POINTS_FOLD

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
        earlier when its loss stalls, by ``tolerance``).
    views_per_iteration : int
        Photos rendered per iteration (a seeded sweep through all of them).
    lr : float
        Step of the smooth parameterisation, relative to the hull's box diagonal.
    lr_decay : float
        Step at the end of each stage relative to its start (exponential decay), in (0, 1].
    albedo_lr : float
        Adam step of the albedo; 0: kept at ``albedo`` (``--fixed-albedo``).
    lam : float
        ``lambda`` of the ``(I + lambda L)`` parameterisation (:mod:`mi_loop.ad.smoothing`).
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
    lighting : {'given', 'sh'}
        ``'given'``: the surface is lit by the emitters (``--emitters``);
        ``'sh'``: by spherical-harmonic lighting estimated with the shape and
        the albedo (:mod:`mi_loop.render.lighting`), the emitters only the backdrop.
    exposure : bool
        With ``lighting='sh'``: estimate an RGB gain per photo (exposure, white balance).
    light_lr : float
        Adam step of the lighting's coefficients and the photos' log-gains.
    albedo_smooth : float
        Weight ``w`` of the albedo's term ``w |L c|^2 / n`` (uniform Laplacian of
        the cage): a smooth albedo leaves shading to the geometry; 0: off.
    highlights : float
        ``t > 0``: leave out of the loss the pixels inside the mask whose target
        luminance exceeds ``t`` times the render's plus 0.02 (highlights the
        diffuse model cannot show); 0: off.
    holdout : int
        ``K``: ``mi-loop fit-images`` leaves every ``K``-th photo (``i % K == K - 1``)
        out of the fit and scores the fit on them (:mod:`mi_loop.fitting.holdout`);
        0: none, else >= 2. :func:`~mi_loop.fitting.images.fit_images` fits the
        views it is given.
    """

    n_vertices: int = option(900, rule=at_least(4), flag="--vertices", metavar="N",
                             help="most control vertices, after --refinements exact Loop steps (default %(default)s)")
    init: str = option("hull", rule=one_of(IMAGE_INITS), metavar="hull|sphere|MESH", paths=True,
                       help="start shape: a template of the visual hull of the masks (hull, default), an icosphere "
                            "in the hull's box (sphere), or a control mesh file")
    refinements: int = option(1, rule=integers(0, 4), metavar="N",
                              help="exact Loop refinements of the control mesh, coarse to fine (default %(default)s)")
    resolution: int | None = option(None, rule=at_least(16).or_none("the photos' size"), flag="--res", metavar="R",
                                    help="longest image side at the finest stage, in pixels (default: the photos' "
                                         "own; coarser stages halve it)")
    spp: int = option(4, rule=COUNT, help=SPP_HELP)
    iterations: int = option(300, rule=COUNT, metavar="N",
                             help="most iterations of all stages together; a stage stops earlier when --tolerance "
                                  "says it has converged (default %(default)s)")
    views_per_iteration: int = option(2, rule=COUNT, metavar="K",
                                      help="photos rendered per iteration (default %(default)s)")
    lr: float = option(0.01, rule=POSITIVE,
                       help="step size relative to the visual hull's box diagonal (default %(default)s)")
    lr_decay: float = option(1.0, rule=interval(0, 1, open_low=True),
                             help="step at the end of each stage relative to its start (default %(default)s)")
    albedo_lr: float = option(0.02, rule=WEIGHT,
                              help="Adam step of the per-control-vertex albedo (default %(default)s; 0: kept at "
                                   "--albedo)",
                              presets=(("--fixed-albedo", 0.0, "keep the albedo at --albedo (--albedo-lr 0)"),))
    lam: float = option(20.0, rule=WEIGHT,
                        help="lambda of the (I + lambda L)^-1 smoothing over the cage of every step, LargeSteps' "
                             "parameterisation (default %(default)s; 0: off)")
    laplacian: float = option(0.05, rule=WEIGHT, deprecated=("--smooth",),
                              help="weight of the cage's Laplacian term, which keeps control vertices spread "
                                   "(default %(default)s; 0: off)")
    albedo: float = option(0.5, rule=interval(0, 1), help="start albedo, grey (default %(default)s)")
    tolerance: float = option(0.005, rule=WEIGHT, deprecated=("--stall",),
                              help="relative fall of the mean loss over two sweeps of the photos below which a stage "
                                   "stops, after half its iterations (default %(default)s; 0: never)")
    triangles: int = option(20_000, rule=COUNT, metavar="N",
                            help="rendered triangles per stage, roughly: sets the tessellation level "
                                 "(default %(default)s)")
    integrator: str = option("direct_projective", rule=one_of(INTEGRATORS),
                             help="differentiable integrator (default %(default)s)")
    seed: int = option(0, rule=SEED, help=SEED_HELP.format("the view order and of the renders",
                                                           "with --deterministic "))
    deterministic: bool = option(False, rule=FLAG,
                                 help="bit-reproducible fit: the reverse renders run on one thread (slower)")
    lighting: str = option("given", rule=one_of(LIGHTINGS), help=LIGHTING_HELP)
    exposure: bool = option(True, rule=FLAG, flag="--no-exposure", help=EXPOSURE_HELP)
    light_lr: float = option(0.01, rule=WEIGHT, help=LIGHT_LR_HELP)
    albedo_smooth: float = option(0.0, rule=WEIGHT, metavar="W",
                                  help="weight of the albedo's Laplacian over the cage, so that shading is explained "
                                       "by the geometry rather than painted into the albedo (default %(default)s: off)")
    highlights: float = option(0.0, rule=WEIGHT, metavar="T",
                               help="leave out pixels inside the mask brighter than T times the render (highlights); "
                                    "default %(default)s: off")
    holdout: int = option(0, rule=HOLDOUT, metavar="K",
                          help="leave every K-th photo (the K-th, 2K-th, ...) out of the fit and score the fit on "
                               "them: silhouette IoU and PSNR inside the mask (default %(default)s: off)")

    def __post_init__(self):
        check_fields(self)
