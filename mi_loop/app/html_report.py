"""``report.html``: one self-contained page per result, drawn by the vendored three.js (its files read through io).

A page needs nothing but itself: opened from the file system (``file://``)
without a network it has everything inlined, as classic scripts (a page on
``file://`` cannot load ES modules or fetch files): three.js r187 and its
OrbitControls (MIT, ``viewer/three.LICENSE``; ``viewer/three.min.js`` is built
by ``viewer/build-three.sh`` from ``viewer/three-entry.js``), the viewer
(``viewer/report.js``, ``viewer/report.css``) and the data, as base64 arrays in a
``<script type="application/json">``: indices as uint32, positions as uint16
over their bounding box (1/65535 of it), unit normals as int16, colours as
uint8, distances as uint16 over their range. Pictures are PNG ``data:`` URIs.

- :func:`static_page`: ``fit`` and ``fit-images``: the limit surface (smooth,
  exact limit normals) coloured by its distance to the data or by its albedo,
  with a legend; the data points, the control cage, creases, camera frusta;
  tables, the loss plot, photos next to renders;
- :func:`sequence_page`: ``fit-sequence``: the same surface for every frame,
  a frame slider with play and pause, per-frame plots with the frame marked;
- :func:`index_page`: ``fit-batch``: the summary table, each input linked to its report.

For automated checks: once the 3D view has drawn, its ``<canvas id="view">``
carries ``data-drawn``, the triangles three.js drew in its last frame (those
of the limit surface: points and lines are not triangles), and in a sequence
``data-frame``, the frame shown.
"""
from __future__ import annotations

import base64
import html
import json

import numpy as np

from mi_loop.errors import fail
from mi_loop.io.documents import read_package_text

__all__ = ["THREE_REVISION", "index_page", "sequence_page", "static_page"]

#: The three.js release that ``viewer/three.min.js`` bundles.
THREE_REVISION = "187"
#: Share of the distances below the top of the colour scale (the rest get its top colour).
_TOP_QUANTILE = 0.98


def _asset(name: str) -> str:
    """The viewer's file ``name`` (``mi_loop/app/viewer/``), read through :mod:`mi_loop.io`."""
    return read_package_text("mi_loop.app", "viewer", name)


def _script(text: str) -> str:
    """Text safe inside ``<script>``: no ``</script`` can end the element early."""
    return text.replace("</script", "<\\/script").replace("</SCRIPT", "<\\/SCRIPT")


def _array(a, kind: str) -> dict:
    """Encode an array for ``report.js``'s ``decode``: ``u4`` indices, ``q16`` floats, ``n16`` unit vectors,
    ``c8`` colours in [0, 1], ``f4`` floats; rows of ``a.shape[-1]`` columns."""
    a = np.asarray(a)
    a = a.reshape(-1, a.shape[-1] if a.ndim > 1 else 1)
    out = {"kind": kind, "shape": list(a.shape)}
    if kind == "q16":
        lo, hi = a.min(0), a.max(0)
        span = np.where(hi > lo, hi - lo, 1.0)
        data = np.round((a - lo) / span * 65535).astype("<u2")
        out.update(lo=lo.tolist(), hi=(lo + span).tolist())
    elif kind == "n16":
        data = np.round(np.clip(a, -1, 1) * 32767).astype("<i2")
    elif kind == "c8":
        data = np.round(np.clip(a, 0, 1) * 255).astype(np.uint8)
    else:
        data = a.astype({"u4": "<u4", "f4": "<f4"}[kind])
    out["b64"] = base64.b64encode(np.ascontiguousarray(data).tobytes()).decode("ascii")
    return out


def _checked(func: str, name: str, a, shape: tuple, *, integer: bool = False) -> np.ndarray:
    """``a`` as an array of ``shape`` (None: any length), finite; else a ValueError naming ``func`` and ``name``."""
    a = np.asarray(a)
    kind = np.integer if integer else np.number
    if not (a.ndim == len(shape) and all(s is None or s == n for s, n in zip(shape, a.shape)) and a.size > 0
            and np.issubdtype(a.dtype, kind)):
        want = "(" + ", ".join("n" if s is None else str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"
        fail(func, f"{name} of shape {want}, {'integer' if integer else 'numbers'}, not empty",
             f"shape {a.shape}, dtype {a.dtype}")
    if not integer and not np.isfinite(a).all():
        bad = np.argwhere(~np.isfinite(a))[0]
        fail(func, f"finite {name}", f"{a[tuple(bad)]} at index {bad.tolist()}")
    return a


def _faces(func: str, F, n: int) -> np.ndarray:
    F = _checked(func, "F", F, (None, 3), integer=True)
    bad = np.flatnonzero((F < 0).any(1) | (F >= n).any(1))
    if len(bad):
        fail(func, f"faces with indices in [0, {n})", f"{F[bad[0]].tolist()} at face {bad[0]}")
    return F


def _edges(F) -> np.ndarray:
    E = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    return np.unique(E, axis=0)


def _legend(d, title: str) -> dict:
    top = float(np.quantile(d, _TOP_QUANTILE)) if d.size else 0.0
    top = top if top > 0 else max(float(d.max()), 1e-12)
    return {"top": top, "max": float(d.max()), "title": title}


def _number(v) -> str:
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return f"{float(v):.4g}"
    if isinstance(v, (dict, list, tuple)):
        return json.dumps(v, default=str)
    return str(v)


def _tables(tables) -> str:
    parts = []
    for caption, rows in (tables or {}).items():
        body = "".join(f"<tr><th>{html.escape(str(k))}</th><td>{html.escape(_number(v))}</td></tr>"
                       for k, v in rows.items())
        parts.append(f'<table class="metrics"><caption>{html.escape(caption)}</caption>{body}</table>')
    return "\n".join(parts)


def _img(png: bytes, alt: str) -> str:
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{base64.b64encode(png).decode("ascii")}">'


def _controls(payload: dict) -> str:
    """The view's controls: colouring, layers that exist; the player of a sequence."""
    colour = [(f"field-{i}", f"distance to {f['name']}") for i, f in enumerate(payload["fields"])]
    colour += [("albedo", "albedo")] if payload["C"] else []
    colour += [("plain", "plain")]
    options = "".join(f'<option value="{v}">{html.escape(label)}</option>' for v, label in colour)
    parts = [f'<label>colour <select id="colour">{options}</select></label>']
    layers = [("points", "data points", True), ("cage", "control cage", False), ("creases", "creases", True),
              ("frusta", "cameras", True)]
    for key, label, on in layers:
        if payload[key]:
            parts.append(f'<label><input type="checkbox" id="show-{key}"{" checked" if on else ""}> {label}</label>')
    controls = f'<div class="controls">{" ".join(parts)}</div>'
    if payload["kind"] == "sequence":
        controls += ('<div class="player"><button id="play" type="button">play</button>'
                     f'<input type="range" id="frame" min="0" max="{payload["frames"] - 1}" step="1" value="0">'
                     '<output id="frame-label"></output></div>')
    return controls


def _page(title: str, subtitle: str, payload: dict, side: str, below: str = "", under_view: str = "") -> str:
    js_licence = "/*! three.js r" + THREE_REVISION + " (threejs.org), bundled with its OrbitControls:\n" \
        + _asset("three.LICENSE").replace("*/", "* /") + "*/\n"
    data = json.dumps(payload, separators=(",", ":"), allow_nan=False).replace("<", "\\u003c")
    return f"""<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{html.escape(title)}</title>
<style>
{_asset("report.css")}
</style>
</head>
<body>
<header><h1>{html.escape(title)}</h1><p class="subtitle">{html.escape(subtitle)}</p></header>
<main>
<section class="view-panel">
<div class="viewer"><canvas id="view" data-drawn="0"></canvas><div id="legend" class="legend"></div></div>
{_controls(payload)}
<p class="hint">Drag to turn, right-drag or shift-drag to move, wheel to zoom.</p>
{under_view}
</section>
<section class="side">
{side}
</section>
{below}
</main>
<footer>Written by mi_loop. 3D view: three.js r{THREE_REVISION} (MIT licence), inlined; the page works offline.</footer>
<script type="application/json" id="mi-loop-data">{data}</script>
<script>
{_script(js_licence + _asset("three.min.js"))}
</script>
<script>
{_script(_asset("report.js"))}
</script>
</body>
</html>
"""


def _distances(func: str, distances, shape: tuple) -> dict:
    """``distances`` (None, or what they are to -> array) checked against ``shape``."""
    if distances is not None and not isinstance(distances, dict):
        fail(func, "distances as a dict: what they are to (e.g. 'the data') -> array", type(distances).__name__)
    return {str(name): _checked(func, f"distances['{name}']", d, shape) for name, d in (distances or {}).items()}


def _payload(kind, V, F, N, distances: dict, colors, cage, names, fps) -> dict:
    return {"kind": kind, "frames": len(V), "names": list(names), "fps": float(fps),
            "F": _array(F, "u4"), "P": _array(V, "q16"), "N": _array(N, "n16"),
            "fields": [{"name": name, "d": _array(d, "q16"),
                        "legend": _legend(d, f"distance to {name}, % of its bounding-box diagonal")}
                       for name, d in distances.items()],
            "C": None if colors is None else _array(colors, "c8"),
            "cage": None if cage is None else {"P": _array(cage[0], "q16"), "E": _array(_edges(cage[1]), "u4"),
                                               "n": int(cage[0].shape[-2])},
            "points": None, "creases": None, "frusta": None, "plots": None}


def static_page(title: str, V, F, N, *, subtitle: str = "", distances=None, colors=None, points=None, cage=None,
                creases=None, frusta=None, tables=None, loss_png: bytes | None = None, photos=None,
                figures=None) -> str:
    """Return the ``report.html`` of one surface (``fit``, ``fit-images``) as text.

    Parameters
    ----------
    title, subtitle : str
        The page's heading and the line under it.
    V : (k, 3) float NumPy array
        Limit points of the viewer's tessellation.
    F : (m, 3) int NumPy array
        Its triangles.
    N : (k, 3) float NumPy array
        Unit limit normals at ``V``.
    distances : dict, optional
        What the distances are to (``'the data'``, ``'the clean torus'``) -> ``(k,)`` float NumPy
        array: the distance of each point of ``V`` to it, relative to its bounding-box diagonal.
        Each is a colouring of the surface, the first one shown first.
    colors : (k, 3) float NumPy array, optional
        Linear RGB in [0, 1] (the albedo of fit-images).
    points : (p, 3) float NumPy array, optional
        Data points to draw (a subsample).
    cage : tuple ``(V_c (n, 3) float, F_c (f, 3) int)``, optional
        The control mesh, drawn as a wireframe.
    creases : (c, s, 3) float NumPy array, optional
        Crease curves on the limit surface, ``s`` points each.
    frusta : (e, 2, 3) float NumPy array, optional
        Line segments of camera frusta.
    tables : dict of dict, optional
        Caption -> {row label: value}, shown as tables.
    loss_png : bytes, optional
        The loss plot, a PNG file.
    photos : list of ``(caption, photo_png, render_png)``, optional
        Photos next to renders of the fit from the same cameras.
    figures : list of ``(caption, png)``, optional
        More pictures, each under its own heading, below the photos (``holdout.png``).

    Returns
    -------
    str
        The page.

    Raises
    ------
    ValueError
        An array of the wrong shape, not finite, or faces out of range; distances not a dict.
    """
    where = "static_page"
    V = _checked(where, "V", V, (None, 3))
    F, N = _faces(where, F, len(V)), _checked(where, "N", N, (len(V), 3))
    d = _distances(where, distances, (len(V),))
    C = None if colors is None else _checked(where, "colors", colors, (len(V), 3))
    if cage is not None:
        Vc = _checked(where, "cage vertices", cage[0], (None, 3))
        cage = (Vc, _faces(where, cage[1], len(Vc)))
    payload = _payload("static", V[None], F, N[None], d, C, cage, [title], 1.0)
    if points is not None:
        payload["points"] = _array(_checked(where, "points", points, (None, 3)), "q16")
    if creases is not None:
        c = _checked(where, "creases", creases, (None, None, 3))
        payload["creases"] = _array(np.stack([c[:, :-1], c[:, 1:]], axis=2), "f4")
    if frusta is not None:
        payload["frusta"] = _array(_checked(where, "frusta", frusta, (None, 2, 3)), "f4")
    loss = "" if loss_png is None else f'<figure class="plot">{_img(loss_png, "loss per iteration")}</figure>'
    below = ""
    if photos:
        cells = "".join(f'<figure class="pair">{_img(p, "photo")}{_img(r, "render of the fit")}'
                        f"<figcaption>{html.escape(caption)}</figcaption></figure>" for caption, p, r in photos)
        below = (f'<section class="photos"><h2>Photos (left) and renders of the fit from the same cameras '
                 f"(right)</h2><div class=\"pairs\">{cells}</div></section>")
    below += "".join(f'<section class="photos"><h2>{html.escape(caption)}</h2><figure>{_img(png, caption)}</figure>'
                     "</section>" for caption, png in figures or ())
    return _page(title, subtitle, payload, _tables(tables), below, loss)


def sequence_page(title: str, V, F, N, *, names, fps: float, subtitle: str = "", distances=None, colors=None,
                  cages=None, plots=None, tables=None) -> str:
    """Return the ``report.html`` of a sequence (``fit-sequence``) as text: every frame, a player, plots.

    Parameters
    ----------
    title, subtitle : str
        The page's heading and the line under it.
    V : (T, k, 3) float NumPy array
        Limit points of every frame, at the viewer's tessellation (one connectivity).
    F : (m, 3) int NumPy array
        The triangles.
    N : (T, k, 3) float NumPy array
        Unit limit normals.
    names : list of str
        The frames' names (``T``).
    fps : float
        Frames per second of the player (> 0).
    distances : dict, optional
        What the distances are to (``"the frame's target"``) -> ``(T, k)`` float NumPy array: the
        distance of each point to it in its frame, relative to its bounding-box diagonal.
    colors : (T, k, 3) float NumPy array, optional
        Linear RGB in [0, 1] (the albedo of fits to photos).
    cages : tuple ``(V_c (T, n, 3) float, F_c (f, 3) int)``, optional
        The control mesh of every frame.
    plots : dict, optional
        ``frames`` (T frame numbers) and ``panels``, a list of ``{"title", "series": {label: (T,) values}}``;
        NaN where not measured (a panel with nothing finite is left out).
    tables : dict of dict, optional
        Caption -> {row label: value}.

    Returns
    -------
    str
        The page.

    Raises
    ------
    ValueError
        An array of the wrong shape or not finite, faces out of range, names or plots not one per frame,
        a frame rate that is not positive.
    """
    where = "sequence_page"
    V = _checked(where, "V", V, (None, None, 3))
    T, k = V.shape[:2]
    F, N = _faces(where, F, k), _checked(where, "N", N, (T, k, 3))
    d = _distances(where, distances, (T, k))
    C = None if colors is None else _checked(where, "colors", colors, (T, k, 3))
    if len(names) != T:
        fail(where, f"one name per frame ({T})", f"{len(names)} names")
    if not fps > 0:
        fail(where, "a frame rate fps > 0", fps)
    if cages is not None:
        Vc = _checked(where, "cage vertices", cages[0], (T, None, 3))
        cages = (Vc, _faces(where, cages[1], Vc.shape[1]))
    payload = _payload("sequence", V, F, N, d, C, cages, [str(n) for n in names], fps)
    if plots is not None:
        panels = []
        for panel in plots["panels"]:
            series = {}
            for label, values in panel["series"].items():
                values = np.asarray(values, dtype=float)
                if values.shape != (T,):
                    fail(where, f"plot values, one per frame ({T})", f"shape {values.shape} for '{label}'")
                if np.isfinite(values).any():
                    series[label] = [float(v) if np.isfinite(v) else None for v in values]
            if series:
                panels.append({"title": panel["title"], "series": series})
        payload["plots"] = {"frames": [int(t) for t in plots["frames"]], "panels": panels}
    side = '<div id="plots" class="plots"></div>\n' + _tables(tables)
    return _page(title, subtitle, payload, side)


def index_page(title: str, columns, rows, links) -> str:
    """Return the ``report.html`` of a batch as text: its summary table, each input linked to its report.

    Parameters
    ----------
    title : str
        The page's heading.
    columns : sequence of str
        The table's columns (``summary.csv``'s).
    rows : list of dict
        One row per input: column -> value (missing: empty).
    links : list of str or None
        Per row, the relative address of the input's ``report.html``, or None (no report).

    Returns
    -------
    str
        The page (no script: a table and links).
    """
    head = "".join(f"<th>{html.escape(c)}</th>" for c in ["report", *columns])
    body = []
    for row, link in zip(rows, links):
        cell = f'<a href="{html.escape(link)}">report</a>' if link else ""
        cells = "".join(f'<td class="{html.escape(c)}">{html.escape(_number(row.get(c, "")))}</td>'
                        for c in columns)
        body.append(f'<tr class="{html.escape(str(row.get("status", "")))}"><td>{cell}</td>{cells}</tr>')
    return f"""<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>{html.escape(title)}</title>
<style>
{_asset("report.css")}
</style>
</head>
<body>
<header><h1>{html.escape(title)}</h1><p class="subtitle">{len(rows)} inputs: each one's report.html is linked.</p>
</header>
<main><section class="wide"><table class="summary"><thead><tr>{head}</tr></thead>
<tbody>{"".join(body)}</tbody></table></section></main>
<footer>Written by mi_loop.</footer>
</body>
</html>
"""
