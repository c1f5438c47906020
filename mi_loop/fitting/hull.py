"""Where the subject is, from the cameras and masks alone: the capture's bounds and its visual hull.

A capture says nothing about scale or position except through its cameras:
:func:`capture_bounds` takes the point nearest to every optical axis (the
cameras look at the subject) and the largest ball any camera sees there;
:func:`carve` carves a voxel grid over that ball with the masks, by vote
(:class:`Carving`); :func:`hull_points` turns the carved grid into oriented
points on its boundary, and :func:`visual_hull` does both, giving a box for
the initial sphere and oriented points for a template. NumPy only.

The carving survives real masks (:func:`carve`'s Notes say how): a view votes
only on voxels inside its frame, in front of it, on pixels it saw, and only
where its mask is certain (:func:`mi_loop.render.mask_trust.mask_votes`); a
few wrong masks are outvoted; space that too few views see is not kept.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from mi_loop.errors import fail
from mi_loop.render.mask_trust import MASK_BAND, check_band, mask_votes

__all__ = ["MIN_SHARE", "OUTVOTE", "Carving", "capture_bounds", "carve", "hull_points", "in_mask", "visual_hull"]

#: Share of the views that must see a voxel (in frame, in front, on a seen pixel) for it to be kept at all.
MIN_SHARE = 0.25
#: Share of the deciding views whose "background" a voxel survives (wrong masks), rounded down.
OUTVOTE = 0.1
#: Boundary points whose smoothed-occupancy gradient is below this (per voxel) have no orientation: dropped.
MIN_GRADIENT = 0.02


def capture_bounds(cameras) -> tuple[np.ndarray, float]:
    """Return the point nearest to every optical axis and a radius around it that holds the subject.

    Parameters
    ----------
    cameras : sequence of mi_loop.io.capture.Camera
        At least two cameras with non-parallel optical axes.

    Returns
    -------
    centre : (3,) float64 NumPy array
        Least-squares nearest point to the optical axes (the OpenGL ``-Z`` of each ``c2w``).
    radius : float
        The radius of the largest ball about ``centre`` that one camera sees
        whole (its distance times the sine of its narrower half field of view).

    Raises
    ------
    ValueError
        If the optical axes do not determine a point (fewer than two cameras, parallel axes).
    """
    A, b = np.zeros((3, 3)), np.zeros(3)
    for cam in cameras:
        o, d = cam.c2w[:3, 3], -cam.c2w[:3, 2] / np.linalg.norm(cam.c2w[:3, 2])
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ o
    if len(cameras) < 2 or np.linalg.cond(A) > 1e8:
        fail("capture_bounds", "cameras whose optical axes meet near one point (two or more, not parallel)",
             f"{len(cameras)} camera(s)")
    centre = np.linalg.solve(A, b)
    radii = []
    for cam in cameras:
        half = min(np.arctan(0.5 * cam.width / cam.fx), np.arctan(0.5 * cam.height / cam.fy))
        radii.append(np.linalg.norm(cam.c2w[:3, 3] - centre) * np.sin(half))
    return centre, float(max(radii))


def _seen_pixels(view, X):
    """``(inside, px)``: the points ``view`` sees (in front, in frame, on a pixel seen at least half), their pixels."""
    from mi_loop.render.cameras import project

    cam = view.camera
    ahead = (X - cam.c2w[:3, 3]) @ -cam.c2w[:3, 2] > 0
    uv = project(cam, X)
    inside = ahead & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
    px = np.clip(uv[inside].astype(np.int64), 0, [cam.width - 1, cam.height - 1])
    if view.valid is not None:                   # unseen pixels of an undistorted photo say nothing
        seen = view.valid[px[:, 1], px[:, 0]] >= 0.5
        inside[np.flatnonzero(inside)[~seen]] = False
        px = px[seen]
    return inside, px


def in_mask(view, X, threshold: float = 0.5, margin: int = 0):
    """Which points a photo sees, and which of those fall inside its mask.

    Parameters
    ----------
    view : mi_loop.io.capture.View
        The photo, its camera and mask.
    X : (k, 3) float NumPy array
        Points, in the capture's units.
    threshold : float
        Mask value below which a pixel is background.
    margin : int
        The foreground grown by this many pixels (8-neighbours) first: a point that far outside still counts.

    Returns
    -------
    inside : (k,) bool NumPy array
        In front of the camera, within the image and, in an undistorted photo,
        on a pixel the photo saw at least half of (``view.valid >= 0.5``).
    foreground : (inside.sum(),) bool NumPy array
        For the points ``X[inside]``: the mask at their pixel is ``>= threshold``.
    """
    inside, px = _seen_pixels(view, X)
    fore = view.mask >= threshold
    if margin > 0:
        from scipy.ndimage import binary_dilation

        fore = binary_dilation(fore, structure=np.ones((3, 3), bool), iterations=margin)
    return inside, fore[px[:, 1], px[:, 0]]


@dataclass(frozen=True, eq=False)
class Carving:
    """A voxel grid carved by the masks' votes (:func:`carve`).

    Attributes
    ----------
    occupied : (r, r, r) bool NumPy array
        The kept voxels: one connected part (26-neighbours), without enclosed cavities.
    centres : (r, r, r, 3) float64 NumPy array
        Voxel centres, capture units; axis ``i`` of the grid is world axis ``i``.
    seen, inside, outside : (r, r, r) int64 NumPy arrays
        Per voxel: the views that see it; of those, the ones whose mask says
        foreground, and background (the rest are uncertain there).
    voxel : float
        Edge length of a voxel.
    info : dict
        ``views``, ``min_views`` (views a kept voxel needs), ``unseen`` (voxels
        seen by fewer), ``voted_out`` (carved by votes), ``outvoted`` (kept
        against at least one background vote), ``dropped_parts`` (voxels in
        parts other than the largest), ``filled`` (voxels of enclosed cavities),
        ``kept``.
    """

    occupied: np.ndarray
    centres: np.ndarray
    seen: np.ndarray
    inside: np.ndarray
    outside: np.ndarray
    voxel: float
    info: dict = field(default_factory=dict)


def _check_share(value, func: str, name: str, low: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not low <= value < 1:
        fail(func, f"{name} in [{low:g}, 1)", value)
    return float(value)


def carve(views, *, resolution: int = 64, band=MASK_BAND, min_share: float = MIN_SHARE,
          outvote: float = OUTVOTE) -> Carving:
    """Carve a voxel grid over :func:`capture_bounds` by the votes of the masks of ``views``.

    Parameters
    ----------
    views : sequence of mi_loop.io.capture.View
        Photos with foreground masks and cameras (``valid`` respected).
    resolution : int
        Voxels along each side of the cube of :func:`capture_bounds`, >= 8.
    band : (float, float)
        Uncertainty band of the masks (:data:`~mi_loop.render.mask_trust.MASK_BAND`).
    min_share : float
        Share of the views that must see a voxel for it to be kept, in [0, 1).
    outvote : float
        Share of the deciding views whose background votes a voxel survives, in [0, 1).

    Returns
    -------
    Carving

    Raises
    ------
    ValueError
        A bad resolution, band or share; cameras that do not meet (:func:`capture_bounds`).

    Notes
    -----
    Each view votes on each voxel centre ``x`` by the pixel ``x`` falls in:
    it abstains where ``x`` is behind it, outside its frame or on a pixel it
    did not see (``valid < 0.5``), and where its mask is uncertain
    (:func:`~mi_loop.render.mask_trust.uncertain`: ``lo <= m < hi`` off the
    mask's edge, i.e. blur and JPEG ringing); otherwise it says foreground
    (``m >= 0.5``) or background. With ``s`` views seeing ``x``, ``n_in`` and
    ``n_out`` of them voting so, ``x`` is kept if and only if

    - ``s >= max(2, floor(min_share * n_views))``: space that few views see is
      unconstrained (a subject that leaves most frames is cut where most
      views stop seeing it, instead of leaving a slab of uncarved space), and
    - ``n_out <= floor(outvote * (n_in + n_out))``: a wrong mask (a hole, a
      missing part) is outvoted once ten views decide about the voxel (at the
      default 10 %); with fewer, one background vote carves, as in the
      classic hull.

    Of what is kept, the largest 26-connected part stays (specks of space
    that the votes could not carve are dropped) and enclosed cavities are
    filled; neither changes the genus of the part.

    The price of the vote: a hole that at most one in ten of the views
    deciding about its space look through (a mug's handle seen through from
    a narrow cone of directions only) is kept full and closes; ``outvote=0``
    carves as the classic hull does. A hole must also span a few
    voxels to survive, and a few cells of the template's Poisson octree
    (:func:`~mi_loop.fitting.template.make_template`; depth 6 below 2000
    vertices): a torus's of 40 % of its width does (tested).
    """
    func = "carve"
    if isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)) or resolution < 8:
        fail(func, "an integer resolution >= 8", resolution)
    band = check_band(band, func)
    min_share, outvote = _check_share(min_share, func, "min_share", 0), _check_share(outvote, func, "outvote", 0)
    centre, radius = capture_bounds([v.camera for v in views])
    axis = centre[:, None] + np.linspace(-radius, radius, resolution)[None, :]
    centres = np.stack(np.meshgrid(axis[0], axis[1], axis[2], indexing="ij"), axis=-1)
    X = centres.reshape(-1, 3)
    seen, n_in, n_out = (np.zeros(len(X), dtype=np.int64) for _ in range(3))
    for view in views:
        inside, px = _seen_pixels(view, X)
        idx = np.flatnonzero(inside)
        vote = mask_votes(view.mask, band)[px[:, 1], px[:, 0]]
        seen[idx] += 1
        n_in[idx[vote > 0]] += 1
        n_out[idx[vote < 0]] += 1
    min_views = max(2, math.floor(min_share * len(views)))
    voted = n_out <= np.floor(outvote * (n_in + n_out))
    keep = (seen >= min_views) & voted
    occupied, dropped = _largest_part(keep.reshape((resolution,) * 3))
    filled = ndimage.binary_fill_holes(occupied)
    shape = occupied.shape
    info = {"views": len(views), "min_views": min_views, "unseen": int((seen < min_views).sum()),
            "voted_out": int(((seen >= min_views) & ~voted).sum()), "outvoted": int((keep & (n_out > 0)).sum()),
            "dropped_parts": dropped, "filled": int((filled & ~occupied).sum()), "kept": int(filled.sum())}
    return Carving(filled, centres, seen.reshape(shape), n_in.reshape(shape), n_out.reshape(shape),
                   float(2 * radius / (resolution - 1)), info)


def _largest_part(occupied):
    """The largest 26-connected part of a boolean grid, and the voxels of the others."""
    label, n = ndimage.label(occupied, np.ones((3, 3, 3), dtype=bool))
    if n <= 1:
        return occupied, 0
    sizes = np.bincount(label.ravel())[1:]
    return label == 1 + int(np.argmax(sizes)), int(sizes.sum() - sizes.max())


def hull_points(carving: Carving, *, sigma: float = 1.0):
    """Oriented points on the boundary of a carved grid: voxel centres and smoothed-occupancy normals.

    Parameters
    ----------
    carving : Carving
    sigma : float
        Gaussian smoothing of the occupancy, in voxels, before its gradient is taken.

    Returns
    -------
    P : (k, 3) float64 NumPy array
        Centres of the boundary voxels (kept voxels with an empty 6-neighbour,
        the grid's outside counting as empty).
    N : (k, 3) float64 NumPy array
        Outward unit normals: minus the gradient of the smoothed occupancy.
    dropped : int
        Boundary voxels left out because their gradient is below
        :data:`MIN_GRADIENT` per voxel, so has no direction.

    Notes
    -----
    The occupancy is smoothed with zeros outside the grid: where the hull is
    cut by the grid's faces (a subject larger than what the cameras see
    whole) the cut is a closing face with outward normals. A boundary voxel
    has no gradient where the occupancy is symmetric about it: a lone voxel,
    a plate or rod one voxel thick (the smoothed occupancy's central
    differences cancel exactly). Such points carry no orientation; they are
    dropped instead of being passed on with zero normals.
    """
    occupied = carving.occupied
    boundary = occupied & ~ndimage.binary_erosion(occupied, border_value=0)
    smooth = ndimage.gaussian_filter(occupied.astype(np.float64), sigma, mode="constant", cval=0.0)
    grad = np.stack(np.gradient(smooth), axis=-1)[boundary]
    length = np.linalg.norm(grad, axis=1)
    ok = length >= MIN_GRADIENT
    P = carving.centres[boundary][ok]
    return P, -grad[ok] / length[ok, None], int((~ok).sum())


def visual_hull(views, *, resolution: int = 64, band=MASK_BAND):
    """Carve a voxel grid with the masks of ``views``; return oriented points on the hull and its box.

    Parameters
    ----------
    views : sequence of mi_loop.io.capture.View
        Photos with foreground masks and cameras.
    resolution : int
        Voxels along each side of the cube of :func:`capture_bounds`.
    band : (float, float)
        Uncertainty band of the masks (:func:`carve`).

    Returns
    -------
    P : (k, 3) float64 NumPy array
        Centres of the hull's boundary voxels (:func:`hull_points`).
    N : (k, 3) float64 NumPy array
        Outward unit normals there (gradient of the smoothed occupancy).
    bbox : ((3,), (3,)) float64 NumPy arrays
        Corners of the hull's bounding box (of its voxel centres).

    Raises
    ------
    ValueError
        If nothing survives the carving (masks that contradict each other),
        or no boundary point has a normal (a hull one voxel thin).

    Notes
    -----
    The carving's rules are :func:`carve`'s: views abstain outside their
    frames and on uncertain mask pixels, a few wrong masks are outvoted, and
    space that fewer than a quarter of the views see is cut away.
    """
    carving = carve(views, resolution=resolution, band=band)
    if not carving.occupied.any():
        fail("visual_hull", "masks whose foregrounds overlap in space", "nothing left after carving")
    P, N, _ = hull_points(carving)
    if not len(P):
        fail("visual_hull", "a hull thicker than one voxel", "no oriented boundary point (raise the resolution)")
    kept = carving.centres[carving.occupied]
    return P, N, (kept.min(axis=0), kept.max(axis=0))
