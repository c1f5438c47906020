"""Reports of a fit as data: pictures as pixel arrays (energy curves, drift, renders), JSON-ready dicts.

No file I/O. Figures are drawn on Matplotlib's ``Figure`` with the Agg canvas
(:class:`~matplotlib.backends.backend_agg.FigureCanvasAgg`): ``pyplot`` is
never imported, so the calling program's backend and figures are untouched.
"""
from __future__ import annotations

import numpy as np

__all__ = ["LOSS_TERMS", "agg_figure", "drift_figure", "figure_pixels", "loss_figure", "loss_plot", "plain",
           "side_by_side", "splat_mesh", "strip_figure"]

#: History keys of :attr:`mi_loop.fitting.static.FitResult.history` drawn by :func:`loss_figure`, and labels.
LOSS_TERMS = {"imls": "IMLS (mean f^2)", "cover": "cover * coverage", "arap": "alpha * ARAP / n",
              "fold": "fold * fold barrier"}


def plain(x):
    """Return a JSON-friendly copy of ``x``: NumPy scalars and arrays, tuples and paths as Python values.

    Parameters
    ----------
    x : object
        A value, or dicts and lists of them (nested to any depth).

    Returns
    -------
    object
        Dicts with ``str`` keys, lists for tuples and arrays, Python numbers for
        NumPy scalars, ``str`` for paths; anything else unchanged.

    Examples
    --------
    >>> plain({"n": np.int64(3), "x": np.arange(2), 1: (0.5,)})
    {'n': 3, 'x': [0, 1], '1': [0.5]}
    """
    from pathlib import PurePath

    if isinstance(x, dict):
        return {str(k): plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, PurePath):
        return str(x)
    return x


def agg_figure(width: float, height: float):
    """Return a Matplotlib ``Figure`` on an Agg canvas (no pyplot, no backend switch).

    Parameters
    ----------
    width, height : float
        Size in inches (100 dpi).

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=100)
    FigureCanvasAgg(fig)
    return fig


def figure_pixels(fig) -> np.ndarray:
    """Rasterise a Matplotlib figure with the Agg canvas.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        A figure (its canvas is replaced by an Agg canvas if it has another).

    Returns
    -------
    (h, w, 3) uint8 NumPy array
        RGB pixels at the figure's size and dpi.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = fig.canvas if isinstance(fig.canvas, FigureCanvasAgg) else FigureCanvasAgg(fig)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[:, :, :3].copy()


def loss_figure(history: dict, title: str = "energy per iteration"):
    """Figure of the energy terms of :attr:`mi_loop.fitting.static.FitResult.history` (log scale).

    The total is a wide grey band underneath, every non-zero term a line on
    top of it, so a term that makes up the whole total (often the coverage
    term) stays visible.

    Parameters
    ----------
    history : dict of lists
        ``total`` and the terms of :data:`LOSS_TERMS`, one value per iteration.
    title : str

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig = agg_figure(6.4, 4.0)
    ax = fig.add_subplot()
    it = np.arange(1, len(history["total"]) + 1)
    total = np.asarray(history["total"])
    ax.semilogy(it, np.maximum(total, 1e-30), color="0.6", linewidth=6, alpha=0.5, solid_capstyle="butt",
                label="total E", zorder=1)
    for key, label in LOSS_TERMS.items():
        values = np.asarray(history.get(key, []))
        if len(values) and (values > 0).any():
            ax.semilogy(it, np.maximum(values, 1e-30), linewidth=1.5, label=label, zorder=2)
    positive = [np.asarray(history[k]) for k in ("total", "imls") if k in history]
    floor = min((np.min(v[v > 0], initial=np.inf) for v in positive), default=np.inf)
    if np.isfinite(floor):
        ax.set_ylim(bottom=floor / 10)
    ax.set_xlabel("iteration")
    ax.set_ylabel("energy (unit box)")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    return fig


def loss_plot(history: dict, title: str = "energy per iteration") -> np.ndarray:
    """Return :func:`loss_figure` as pixels.

    Parameters
    ----------
    history : dict of lists
        :attr:`mi_loop.fitting.static.FitResult.history`.
    title : str, optional
        Title of the plot.

    Returns
    -------
    (h, w, 3) uint8 NumPy array
    """
    return figure_pixels(loss_figure(history, title))


def drift_figure(frames, mean, rms, *, flipped=None, drift=None):
    """Per-frame plots of a sequence: distances, and where measured the folds and the correspondence drift.

    Parameters
    ----------
    frames : (T,) int array-like
    mean, rms : (T,) float array-like
        Distances relative to the target's bounding-box diagonal.
    flipped : (T,) float array-like, optional
        Flipped area, % of the limit surface (NaN where not measured).
    drift : (T,) float array-like, optional
        Mean correspondence drift relative to the diagonal (NaN where not measured).

    Returns
    -------
    matplotlib.figure.Figure
        One panel per quantity that has a finite value, integer frame ticks.
    """
    from matplotlib.ticker import MaxNLocator

    panels = [("distance to target / bbox diagonal", "per-frame error", [("mean", mean, "o-"), ("RMS", rms, "s-")])]
    if flipped is not None and np.isfinite(np.asarray(flipped, dtype=float)).any():
        panels.append(("flipped area, % of the surface", "folds", [("flipped", flipped, "o-")]))
    if drift is not None and np.isfinite(np.asarray(drift, dtype=float)).any():
        panels.append(("drift / bbox diagonal", "correspondence drift (mean)", [("drift", drift, "o-")]))
    fig = agg_figure(6.4, 2.6 * len(panels) + 0.6)
    axes = fig.subplots(len(panels), 1, squeeze=False, sharex=True)[:, 0]
    for ax, (ylabel, title, curves) in zip(axes, panels):
        for label, values, style in curves:
            ax.plot(frames, values, style, label=label, markersize=4)
        ax.set_ylabel(ylabel, fontsize=8)
        ax.set_title(title, fontsize=9)
        ax.grid(True, alpha=0.3)
        if len(curves) > 1:
            ax.legend(fontsize=8)
    axes[-1].xaxis.set_major_locator(MaxNLocator(integer=True))
    axes[-1].set_xlabel("frame")
    fig.tight_layout()
    return fig


def crop_to_content(image: np.ndarray, *, halves: int = 1, pad: float = 0.08) -> np.ndarray:
    """Crop a picture of ``halves`` side-by-side panels to the box where any panel differs from its corner.

    Parameters
    ----------
    image : (h, w, 3) float NumPy array
        ``halves`` panels of equal width (a target and a fit).
    halves : int
        Panels; one box (the union over panels) is cut from each.
    pad : float
        Margin around the box, relative to its larger side.

    Returns
    -------
    (h', halves * w', 3) float NumPy array
        The image itself where nothing differs from the background.

    Examples
    --------
    >>> im = np.zeros((10, 20, 3)); im[4:6, 2:4] = 1; im[4:6, 12:14] = 1
    >>> crop_to_content(im, halves=2, pad=0).shape
    (2, 4, 3)
    """
    w = image.shape[1] // halves
    panels = [image[:, k * w:(k + 1) * w] for k in range(halves)]
    busy = np.zeros(panels[0].shape[:2], dtype=bool)
    for p in panels:
        busy |= np.abs(p - p[0, 0]).max(axis=2) > 0.02
    if not busy.any():
        return image
    ys, xs = np.nonzero(busy)
    m = int(pad * max(np.ptp(ys) + 1, np.ptp(xs) + 1))
    y0, y1 = max(0, ys.min() - m), min(busy.shape[0], ys.max() + m + 1)
    x0, x1 = max(0, xs.min() - m), min(busy.shape[1], xs.max() + m + 1)
    return np.concatenate([p[y0:y1, x0:x1] for p in panels], axis=1)


def strip_figure(strips, label: str = "target (left), fit (right)"):
    """Target and fit side by side for a few frames, one row each.

    Parameters
    ----------
    strips : list of ``(frame, mean, image)``
        ``image`` from :func:`side_by_side` (or a photo next to a render of the fit).
    label : str
        What the two halves show, in each row's title.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig = agg_figure(4.0, 2.1 * len(strips))
    axes = fig.subplots(len(strips), 1, squeeze=False)
    for ax, (t, mean, image) in zip(axes[:, 0], strips):
        ax.imshow(image)
        ax.set_axis_off()
        ax.set_title(f"frame {t}: {label}; mean {mean:.1e}", fontsize=8)
    fig.tight_layout()
    return fig


def splat_mesh(P: np.ndarray, N: np.ndarray, radius: float):
    """Return one small triangle per oriented point, facing its normal, for rendering point clouds.

    Parameters
    ----------
    P : (k, 3) float NumPy array
        Points.
    N : (k, 3) float NumPy array
        Their normals (any non-zero length).
    radius : float
        Distance of each triangle's corners from its point.

    Returns
    -------
    V : (3k, 3) float64 NumPy array
        Corners, three per point.
    F : (k, 3) int NumPy array
        One triangle per point, counter-clockwise seen from its normal.
    """
    N = N / np.linalg.norm(N, axis=1, keepdims=True)
    helper = np.where(np.abs(N[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    t1 = np.cross(N, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(N, t1)
    corners = [t1, -0.5 * t1 + 0.866 * t2, -0.5 * t1 - 0.866 * t2]
    V = np.stack([P + radius * c for c in corners], 1).reshape(-1, 3)
    F = np.arange(len(V)).reshape(-1, 3)
    return V, F


def side_by_side(target, fit_V, fit_F, *, resolution: int = 320, spp: int = 32,
                 azimuth: float = 35.0, elevation: float = 20.0, creases=None) -> np.ndarray:
    """Render the target and the fitted limit surface with the same camera.

    Parameters
    ----------
    target : tuple
        ``('mesh', V, F)`` or ``('points', P, N)`` (rendered as oriented splats).
    fit_V, fit_F : (n, 3) float and (m, 3) int NumPy arrays
        Fitted control mesh; its limit surface is rendered by ``loop_subdiv``.
    resolution : int, optional
        Height of the picture and width of each half, pixels.
    spp : int, optional
        Samples per pixel.
    azimuth, elevation : float, optional
        Camera direction, degrees.
    creases : (c, 2) int NumPy array, optional
        Crease edges of the fitted control mesh.

    Returns
    -------
    (resolution, 2 * resolution, 3) float32 numpy array
        Display sRGB in [0, 1]: target left, fit right.
    """
    import mitsuba as mi

    from mi_loop.render.plugin import create, plain_mesh
    from mi_loop.render.scene import PLASTIC, render_view, scene_dict, to_srgb

    kind, A, B = target
    if kind == "points":
        spacing = np.linalg.norm(A.max(0) - A.min(0)) / np.sqrt(len(A)) * 2.0
        A, B = splat_mesh(A, B, spacing)
    bbox = (A.min(0), A.max(0))
    grey = {"type": "plastic", "diffuse_reflectance": {"type": "rgb", "value": [0.55, 0.55, 0.52]}}
    shapes = [plain_mesh(A, B, bsdf=mi.load_dict(grey)),
              create(fit_V, fit_F, level=2, creases=creases, bsdf=mi.load_dict(PLASTIC))]
    images = []
    for shape in shapes:
        scene = mi.load_dict(scene_dict(shape, views=[(azimuth, elevation)], resolution=resolution,
                                        bbox=bbox))
        images.append(to_srgb(render_view(scene, spp=spp, seed=0)))
    return np.concatenate(images, axis=1)
