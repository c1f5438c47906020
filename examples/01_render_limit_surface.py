"""Render the XML scene scenes/blob.xml, whose shape is a ``loop_subdiv`` limit surface.

Run from the repository root:  .venv/bin/python examples/01_render_limit_surface.py
Writes out/01_blob.png (about 10 s on 2 CPU cores, most of it kernel compilation).
"""
from __future__ import annotations

import os
import time
from pathlib import Path

import mitsuba as mi

import mi_loop
from mi_loop import datasets, io, render

REPO = Path(__file__).resolve().parent.parent
OUT = Path(os.environ.get("MI_LOOP_EXAMPLES_OUT", REPO / "out"))   # tests write elsewhere


def main() -> None:
    start = time.perf_counter()
    mi_loop.set_variant("llvm_ad_rgb")          # also registers the loop_subdiv plugin
    scene_file = REPO / "scenes" / "blob.xml"
    control = scene_file.with_name("blob.ply")
    if not control.exists():                    # normally committed; regenerate if deleted
        io.write_ply(control, *datasets.blob())

    scene = mi.load_file(str(scene_file), spp=64, res=256, level=3)
    shape = next(s for s in scene.shapes() if s.id() == "blob")
    print(f"{shape}  bbox {shape.bbox().min} .. {shape.bbox().max}")

    image = render.render_view(scene, spp=64, seed=0)
    io.ensure_writable_dir(OUT)
    path = io.write_png(OUT / "01_blob.png", render.to_srgb(image))
    print(f"wrote {path} in {time.perf_counter() - start:.1f} s")


if __name__ == "__main__":
    main()
