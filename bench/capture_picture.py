"""The README's picture of a real capture: held-out photos, the fit rendered from their cameras, its geometry.

Reads a ``fit-images --holdout K`` output directory (``control.ply``, ``report.json``) and the
capture it fitted; for the first ``--columns`` held-out photos writes three rows: the photo,
the fitted limit surface from the same camera (its albedo, under the lighting the fit
estimated, gain 1) and its geometry alone in grey under a side light
(``render_geometry``). Each tile is cropped to the square around the photo's mask.

    .venv/bin/python bench/capture_picture.py bench/results/real/ethiopian_head/mi-loop-lighting-sh \
        ../shared/data/real/ethiopian_head -o docs/real_capture.png --res 400
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

import mi_loop


def crop_box(mask, margin: float = 0.08):
    """The square (row, col, side) around a mask's foreground, widened by ``margin``, inside the image."""
    rows, cols = np.nonzero(mask > 0.5)
    side = int(max(np.ptp(rows), np.ptp(cols)) * (1 + 2 * margin)) + 1
    side = min(side, *mask.shape)
    r0 = int(np.clip((rows.min() + rows.max() - side) // 2, 0, mask.shape[0] - side))
    c0 = int(np.clip((cols.min() + cols.max() - side) // 2, 0, mask.shape[1] - side))
    return r0, c0, side


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("fit", type=Path)
    parser.add_argument("capture", type=Path)
    parser.add_argument("-o", "--output", type=Path, required=True)
    parser.add_argument("--res", type=int, default=400)
    parser.add_argument("--columns", type=int, default=4)
    parser.add_argument("--tile", type=int, default=200)
    args = parser.parse_args()
    mi_loop.set_variant()
    from mi_loop import io
    from mi_loop.io.capture import read_capture
    from mi_loop.io.srgb import linear_to_srgb
    from mi_loop.io.undistort import area_resize
    from mi_loop.render.captures import render_geometry, render_views
    from mi_loop.render.lighting import Lighting
    from mi_loop.subdiv.masks import limit_colors, limit_mesh

    report = json.loads((args.fit / "report.json").read_text())
    held = [v["index"] for v in report["holdout"]["views"]][:args.columns]
    photos = [read_capture(args.capture, resolution=args.res).views[i] for i in held]
    V, F = io.read_mesh(args.fit / "control.ply")
    albedo = io.read_vertex_colors(args.fit / "control.ply")
    P, F_lim, N = limit_mesh(V, F, 3)
    C = limit_colors(albedo, F, 3)
    lighting = report["lighting"]
    emission = isinstance(lighting, dict)
    if emission:
        C = Lighting(1, np.array(lighting["coefficients"])).shade(C, N)
    cameras = [p.camera for p in photos]
    backdrop = [{"type": "constant", "radiance": {"type": "rgb", "value": 1.0}}]
    renders = [r.rgb for r in render_views(P, F_lim, cameras, backdrop, colors=C, normals=N, spp=32, seed=7,
                                           emission=emission)]
    grey = render_geometry(P, F_lim, N, cameras)
    rows = [[], [], []]
    for photo, render, geometry in zip(photos, renders, grey):
        r0, c0, side = crop_box(photo.mask)
        shown = photo.mask[..., None] * photo.rgb + (1 - photo.mask[..., None])       # the photo over white
        for row, image in zip(rows, (shown, render, geometry)):
            tile = np.asarray(image[r0:r0 + side, c0:c0 + side, :3], dtype=np.float32)
            row.append(linear_to_srgb(area_resize(tile, (args.tile, args.tile)) if side > args.tile else tile))
    size = min(t.shape[0] for row in rows for t in row)
    io.write_png(args.output, np.concatenate([np.concatenate([t[:size, :size] for t in row], axis=1)
                                              for row in rows], axis=0))
    print(args.output)


if __name__ == "__main__":
    main()
