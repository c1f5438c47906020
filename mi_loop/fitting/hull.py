"""Where the subject is, from the cameras and masks alone: the capture's bounds and its visual hull.

A capture says nothing about scale or position except through its cameras:
:func:`capture_bounds` takes the point nearest to every optical axis (the
cameras look at the subject) and the largest ball any camera sees there;
:func:`visual_hull` carves a voxel grid over that ball with the masks (a voxel
stays if every photo that sees it has it inside the mask), giving a box for
the initial sphere and oriented points on the hull for a template. NumPy only.
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage

from mi_loop.errors import fail

__all__ = ["capture_bounds", "in_mask", "visual_hull"]


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


def in_mask(view, X, threshold: float = 0.5):
    """Which points a photo sees, and which of those fall inside its mask.

    Parameters
    ----------
    view : mi_loop.io.capture.View
        The photo, its camera and mask.
    X : (k, 3) float NumPy array
        Points, in the capture's units.
    threshold : float
        Mask value below which a pixel is background.

    Returns
    -------
    inside : (k,) bool NumPy array
        In front of the camera, within the image and, in an undistorted photo,
        on a pixel the photo saw at least half of (``view.valid >= 0.5``).
    foreground : (inside.sum(),) bool NumPy array
        For the points ``X[inside]``: the mask at their pixel is ``>= threshold``.
    """
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
    return inside, view.mask[px[:, 1], px[:, 0]] >= threshold


def visual_hull(views, *, resolution: int = 64, threshold: float = 0.5):
    """Carve a voxel grid with the masks of ``views``; return oriented points on the hull and its box.

    Parameters
    ----------
    views : sequence of mi_loop.io.capture.View
        Photos with foreground masks and cameras.
    resolution : int
        Voxels along each side of the cube of :func:`capture_bounds`.
    threshold : float
        Mask value below which a pixel is background.

    Returns
    -------
    P : (k, 3) float64 NumPy array
        Centres of the hull's boundary voxels.
    N : (k, 3) float64 NumPy array
        Outward unit normals there (gradient of the smoothed occupancy).
    bbox : ((3,), (3,)) float64 NumPy arrays
        Corners of the hull's bounding box.

    Raises
    ------
    ValueError
        If nothing survives the carving (masks that contradict each other).

    Notes
    -----
    A voxel is kept if it projects inside the mask of every photo in whose
    frame it lies (in front of the camera) and lies in the frame of at
    least a quarter of the photos: a subject partly outside some frames is
    not cut there, and the corners of the cube that few cameras see are.
    """
    cameras = [v.camera for v in views]
    centre, radius = capture_bounds(cameras)
    axis = centre[:, None] + np.linspace(-radius, radius, resolution)[None, :]
    X = np.stack(np.meshgrid(axis[0], axis[1], axis[2], indexing="ij"), axis=-1).reshape(-1, 3)
    keep = np.ones(len(X), dtype=bool)
    seen = np.zeros(len(X), dtype=np.int64)
    for view in views:
        inside, fg = in_mask(view, X, threshold)
        idx = np.flatnonzero(inside)
        keep[idx[~fg]] = False
        seen[idx] += 1
    keep &= seen >= max(1, len(views) // 4)
    occupied = keep.reshape((resolution,) * 3)
    if not occupied.any():
        fail("visual_hull", "masks whose foregrounds overlap in space", "nothing left after carving")
    boundary = occupied & ~ndimage.binary_erosion(occupied, border_value=0)
    smooth = ndimage.gaussian_filter(occupied.astype(np.float64), 1.0)
    grad = np.stack(np.gradient(smooth), axis=-1)[boundary]
    N = -grad / np.maximum(np.linalg.norm(grad, axis=1, keepdims=True), 1e-12)
    P = X.reshape(occupied.shape + (3,))[boundary]
    kept = X[keep]
    return P, N, (kept.min(axis=0), kept.max(axis=0))
