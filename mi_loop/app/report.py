"""Pictures of a fit as pixel arrays: energy curves and side-by-side renders (no file I/O)."""
from __future__ import annotations

import numpy as np


def figure_pixels(fig) -> np.ndarray:
    """Rasterise a Matplotlib figure to an ``(h, w, 3)`` uint8 array and close it."""
    import matplotlib.pyplot as plt

    fig.canvas.draw()
    pixels = np.asarray(fig.canvas.buffer_rgba())[:, :, :3].copy()
    plt.close(fig)
    return pixels


def loss_plot(history: dict, title: str = "energy per iteration") -> np.ndarray:
    """Plot the energy terms of :attr:`mi_loop.fit.FitResult.history` (log scale).

    Returns
    -------
    (h, w, 3) uint8 numpy array
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.0), dpi=100)
    it = np.arange(1, len(history["total"]) + 1)
    styles = {"total": {"color": "black", "linestyle": "--", "zorder": 3}}   # on top of the term it follows
    for key, label in (("total", "total E"), ("imls", "IMLS (mean f^2)"), ("cover", "cover * coverage"),
                       ("arap", "alpha * ARAP / n")):
        values = np.asarray(history.get(key, []))
        if len(values) and (values > 0).any():
            ax.semilogy(it, np.maximum(values, 1e-30), label=label, **styles.get(key, {}))
    floor = min(np.min(np.asarray(history[k])[np.asarray(history[k]) > 0], initial=np.inf)
                for k in ("total", "imls"))
    if np.isfinite(floor):
        ax.set_ylim(bottom=floor / 10)
    ax.set_xlabel("iteration")
    ax.set_ylabel("energy (unit box)")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    return figure_pixels(fig)


def splat_mesh(P: np.ndarray, N: np.ndarray, radius: float):
    """One small triangle per oriented point, facing its normal, for rendering point clouds.

    Returns ``(V (3N, 3), F (N, 3))``.
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
                 azimuth: float = 35.0, elevation: float = 20.0) -> np.ndarray:
    """Render the target and the fitted limit surface with the same camera.

    Parameters
    ----------
    target : tuple
        ``('mesh', V, F)`` or ``('points', P, N)`` (rendered as oriented splats).
    fit_V, fit_F : numpy arrays
        Fitted control mesh; its limit surface is rendered by ``loop_subdiv``.

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
              create(fit_V, fit_F, level=2, bsdf=mi.load_dict(PLASTIC))]
    images = []
    for shape in shapes:
        scene = mi.load_dict(scene_dict(shape, views=[(azimuth, elevation)], resolution=resolution,
                                        bbox=bbox))
        images.append(to_srgb(render_view(scene, spp=spp, seed=0)))
    return np.concatenate(images, axis=1)
