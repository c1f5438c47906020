"""``report.html`` (mi_loop.app.html_report, report_data): the pages of real job runs, in a real browser.

Debian's headless Chromium (installed by setup.sh) opens each page from
``file://``, offline, through playwright; one browser serves the module. The
jobs run tiny: a 100-vertex demo fit, the 6-photo capture of
test_images_job.py, a 3-frame sequence, a batch of two spheres and a bad file,
a cube whose edges the fit finds as creases. The checks: no console errors, no
request but the page itself, the 3D canvas's own pixels (``toDataURL``) show a
surface, ``data-drawn`` is the triangle count of the viewer's tessellation
(the limit surface's triangles; points and lines are not triangles), and the
sequence slider and player change the frame and the picture. The page's arrays
and the helpers are tested on small meshes without a browser.
"""
from __future__ import annotations

import base64
import io as stdlib_io
import json
import re
import shutil

import numpy as np
import pytest
import trimesh
from matplotlib.image import imread

from mi_loop import datasets, io
from mi_loop.app import html_report
from mi_loop.app.cli import main
from mi_loop.app.report_data import crease_curves, frustum_segments, subsample, vertex_distances
from mi_loop.subdiv.masks import limit_mesh

from helpers import exactly, run_console, sphere_points, write_xyz

#: Chromium as root in a container, no GPU (WebGL through SwiftShader), no network to talk to.
CHROMIUM_ARGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--no-first-run"]
#: The viewer's background, sRGB (report.js).
BACKGROUND = np.array([0xF4, 0xF4, 0xF2]) / 255


# -- fixtures: the jobs' reports, one browser ---------------------------------------------


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Output directories of ``fit --demo``, ``fit-images``, ``fit-sequence`` and ``fit-batch``."""
    from mi_loop.io.capture import write_capture
    from mi_loop.io.emitters import DEFAULT_EMITTERS
    from mi_loop.render.cameras import fibonacci_cameras
    from mi_loop.render.captures import render_views

    root = tmp_path_factory.mktemp("reports")
    assert main(["fit", "--demo", "-o", str(root / "fit"), "--vertices", "100", "--iterations", "40",
                 "--quiet"]) == 0
    P, F, N = limit_mesh(*datasets.blob(), 2)
    P = (P - P.mean(0)) / np.linalg.norm(P.max(0) - P.min(0))
    cams = fibonacci_cameras(6, [0, 0, 0], 1.9, fov_x_deg=35, width=40, height=32)
    views = render_views(P, F, cams, [dict(e) for e in DEFAULT_EMITTERS], normals=N,
                         colors=np.clip(0.5 + P, 0.1, 0.8), spp=8)
    capture = write_capture(root / "capture", views)
    assert main(["fit-images", str(capture), "-o", str(root / "images"), "--init", "sphere", "--iterations", "6",
                 "--spp", "2", "--vertices", "170", "--refinements", "1", "--quiet"]) == 0
    V, F = datasets.icosphere(2)
    frames = np.stack([V * (1 + 0.1 * t) + [0.3 * t, 0.0, 0.0] for t in range(3)])
    np.savez(root / "seq.npz", vertices=frames, faces=F)
    io.write_ply(root / "control.ply", *datasets.icosphere(1))
    assert main(["fit-sequence", str(root / "seq.npz"), "-o", str(root / "sequence"), "--template",
                 str(root / "control.ply"), "--no-image", "--iterations", "10", "--first-iterations", "20",
                 "--points", "2000", "--fps", "8", "--quiet"]) == 0
    write_xyz(root / "a.xyz", *sphere_points(600, noise=0.01, seed=1))
    write_xyz(root / "b.xyz", *sphere_points(600, radius=0.7, noise=0.01, seed=2))
    (root / "bad.ply").write_text("not a ply file\n")
    batch = run_console("fit-batch", *(str(root / n) for n in ("a.xyz", "b.xyz", "bad.ply")), "-o",
                        str(root / "batch"), "--workers", "2", "--vertices", "30", "--iterations", "5", timeout=240)
    assert batch.returncode == 1 and batch.stdout.split()[-2:] == [str(root / "batch" / n) for n in
                                                                   ("summary.csv", "report.html")], batch.stderr
    cube = trimesh.creation.box(extents=(1, 1, 1)).subdivide().subdivide().subdivide()     # 768 triangles
    io.write_ply(root / "cube.ply", cube.vertices, cube.faces)
    assert main(["fit", str(root / "cube.ply"), "-o", str(root / "creases"), "--vertices", "120", "--iterations", "5",
                 "--quiet"]) == 0
    return {name: root / name for name in ("fit", "images", "sequence", "batch", "creases")}


@pytest.fixture(scope="module")
def browser():
    """Debian's Chromium, headless, through playwright (which downloads no browser of its own)."""
    from playwright.sync_api import sync_playwright

    executable = shutil.which("chromium")
    assert executable, "no chromium on PATH: ./setup.sh installs Debian's chromium"
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=executable, args=CHROMIUM_ARGS)
        yield b
        b.close()


class Page:
    """A report opened from ``file://`` in an offline context, with its console errors and requests."""

    def __init__(self, browser, path):
        self.context = browser.new_context(offline=True, viewport={"width": 1280, "height": 900})
        self.page = self.context.new_page()
        self.errors, self.requests = [], []
        self.page.on("console", lambda m: self.errors.append(m.text) if m.type == "error" else None)
        self.page.on("pageerror", lambda e: self.errors.append(f"page error: {e}"))
        self.page.on("request", lambda r: self.requests.append(r.url))
        self.url = path.as_uri()
        self.page.goto(self.url)

    def drawn(self) -> dict:
        """Wait for the first draw; the canvas's ``data-drawn`` and ``data-frame``."""
        self.page.wait_for_function("document.getElementById('view').dataset.drawn !== '0'", timeout=20_000)
        return self.page.eval_on_selector("#view", "c => ({drawn: c.dataset.drawn, frame: c.dataset.frame})")

    def pixels(self) -> np.ndarray:
        """The 3D canvas's own pixels (its drawing buffer, not the page over it), RGB in [0, 1]."""
        url = self.page.eval_on_selector("#view", "c => c.toDataURL('image/png')")
        return imread(stdlib_io.BytesIO(base64.b64decode(url.split(",", 1)[1])), format="png")[..., :3]

    def close(self):
        self.context.close()

    def check_clean(self):
        """No console error, no page error, no request but the page and its own data: URIs."""
        assert self.errors == []
        assert [u for u in self.requests if u != self.url and not u.startswith("data:")] == []


def surface_mask(image: np.ndarray) -> np.ndarray:
    """Pixels that differ from the viewer's background."""
    return np.abs(image - BACKGROUND).max(axis=2) > 0.08


def check_surface(image: np.ndarray, coloured: bool, share: float = 0.05, height: float = 0.3):
    """The canvas shows a shaded surface, framed: many pixels off the background (``share`` of them at
    least), spread in shading (or in colour for the distance colouring), their bounding box around the
    centre and ``height`` of the canvas's at least."""
    on = surface_mask(image)
    assert on.mean() > share, f"only {on.mean():.3f} of the canvas differs from the background"
    luminance = image[on].mean(axis=1)
    assert luminance.std() > 0.03                                            # shaded, not a flat silhouette
    if coloured:                                                             # viridis, not grey lines or points
        saturated = np.ptp(image, axis=2) > 0.15
        assert saturated.mean() > 0.05, f"only {saturated.mean():.3f} of the canvas in colour"
    ys, xs = np.nonzero(on)
    h, w = on.shape
    assert abs((ys.min() + ys.max()) / 2 / h - 0.5) < 0.15 and abs((xs.min() + xs.max()) / 2 / w - 0.5) < 0.15
    assert np.ptp(ys) > height * h


# -- the jobs' pages in the browser --------------------------------------------------------


def test_the_fit_report_draws_the_limit_surface_coloured_by_distance(runs, browser):
    out = runs["fit"]
    _, F = io.read_mesh(out / "control.ply")
    page = Page(browser, out / "report.html")
    try:
        assert page.drawn() == {"drawn": str(16 * len(F)), "frame": None}     # level 2: 16 triangles per face
        check_surface(page.pixels(), coloured=True)
        legend = page.page.inner_text("#legend")
        assert legend.startswith("distance to the data, % of its bounding-box diagonal") and "largest:" in legend
        text = page.page.inner_text("body")
        report = json.loads((out / "report.json").read_text())
        assert f"{report['metrics']['mean']:.4g}" in text and f"{report['metrics_clean']['mean']:.4g}" in text
        assert page.page.eval_on_selector("figure.plot img", "i => i.naturalWidth") == 640    # loss.png
        before = page.pixels()
        page.page.uncheck("#show-points")
        page.page.check("#show-cage")
        page.page.wait_for_timeout(200)
        assert page.drawn()["drawn"] == str(16 * len(F))                       # lines are not triangles
        changed = np.abs(page.pixels() - before).max(axis=2) > 0.1
        assert changed.mean() > 0.005                                        # points off, cage on
        options = page.page.eval_on_selector_all("#colour option", "os => os.map(o => o.textContent)")
        assert options == ["distance to the data", "distance to the clean torus", "plain"]
        page.page.select_option("#colour", "field-1")
        page.page.wait_for_timeout(200)
        assert page.page.inner_text("#legend").startswith("distance to the clean torus, % of its bounding-box")
        check_surface(page.pixels(), coloured=True)
        page.page.select_option("#colour", "plain")
        page.page.wait_for_timeout(200)
        assert page.page.is_hidden("#legend")
        check_surface(page.pixels(), coloured=False)
        page.check_clean()
    finally:
        page.close()


def test_the_creases_of_a_fit_are_drawn_on_its_limit_surface(runs, browser):
    out = runs["creases"]
    E, _ = io.read_creases(out / "control.ply")
    assert len(E) >= 12                                                      # the cube's 12 edges, split
    page = Page(browser, out / "report.html")
    try:
        page.drawn()
        page.page.uncheck("#show-points")
        page.page.wait_for_timeout(200)
        image = page.pixels()
        check_surface(image, coloured=True)

        def red(im):
            return (im[..., 0] > 0.6) & (im[..., 1] < 0.3) & (im[..., 2] < 0.3)     # report.js's crease colour

        assert page.page.is_checked("#show-creases") and red(image).sum() > 300
        page.page.uncheck("#show-creases")
        page.page.wait_for_timeout(200)
        assert red(page.pixels()).sum() < 0.1 * red(image).sum()
        page.check_clean()
    finally:
        page.close()


def test_the_images_report_shows_photos_renders_and_cameras(runs, browser):
    out = runs["images"]
    _, F = io.read_mesh(out / "control.ply")
    page = Page(browser, out / "report.html")
    try:
        assert page.drawn()["drawn"] == str(16 * len(F))
        page.page.uncheck("#show-frusta")
        page.page.wait_for_timeout(200)
        alone = page.pixels()
        check_surface(alone, coloured=False, share=0.02, height=0.2)            # framed with the cameras
        page.page.check("#show-frusta")
        page.page.wait_for_timeout(200)
        widths = page.page.eval_on_selector_all(".pair img", "ims => ims.map(i => i.naturalWidth)")
        assert widths == [40] * 8                                            # 4 photos and 4 renders, 40 wide
        assert page.page.input_value("#colour") == "albedo" and page.page.is_checked("#show-frusta")
        assert (surface_mask(page.pixels()) & ~surface_mask(alone)).sum() > 200   # the frusta's lines
        page.check_clean()
    finally:
        page.close()


def test_the_sequence_report_plays_and_its_slider_changes_the_frame(runs, browser):
    out = runs["sequence"]
    _, F = io.read_mesh(out / "control" / "0000.ply")
    page = Page(browser, out / "report.html")
    try:
        assert page.drawn() == {"drawn": str(4 * len(F)), "frame": "0"}        # level 1: 4 triangles per face
        first = page.pixels()
        check_surface(first, coloured=True)
        assert page.page.inner_text("#frame-label") == "frame 1 / 3: seq[0]"
        markers = page.page.eval_on_selector_all("#plots line.marker", "ls => ls.map(l => l.getAttribute('x1'))")
        assert len(markers) == 3                                             # distance, folds, drift
        page.page.fill("#frame", "2")
        page.page.wait_for_function("document.getElementById('view').dataset.frame === '2'")
        moved = page.page.eval_on_selector_all("#plots line.marker", "ls => ls.map(l => l.getAttribute('x1'))")
        assert all(float(b) > float(a) for a, b in zip(markers, moved))      # the frame marked further right
        last = page.pixels()
        assert np.mean(surface_mask(first) != surface_mask(last)) > 0.02       # the sphere grew and moved
        page.page.click("#play")
        page.page.wait_for_function("document.getElementById('view').dataset.frame !== '2'", timeout=5_000)
        page.page.click("#play")                                             # pause
        assert page.page.inner_text("#play") == "play"
        frame = page.drawn()["frame"]
        page.page.wait_for_timeout(400)                                      # 8 fps: 3 frames if still playing
        assert page.drawn()["frame"] == frame
        page.check_clean()
    finally:
        page.close()


def test_the_batch_index_links_each_report_and_lists_the_failure(runs, browser):
    out = runs["batch"]
    page = Page(browser, out / "report.html")
    try:
        links = page.page.eval_on_selector_all("a", "as => as.map(a => a.getAttribute('href'))")
        assert links == ["a/report.html", "b/report.html"]
        statuses = page.page.eval_on_selector_all("td.status", "ts => ts.map(t => t.textContent)")
        assert statuses == ["done", "done", "failed"]
        assert "expected a PLY file" in page.page.inner_text("tr.failed td.error")
        page.page.click("a[href='b/report.html']")
        page.page.wait_for_url((out / "b" / "report.html").as_uri())
        _, F = io.read_mesh(out / "b" / "control.ply")
        assert page.drawn()["drawn"] == str(16 * len(F))
        page.url = (out / "b" / "report.html").as_uri()
        assert [u for u in page.requests if not u.startswith("data:")] == [(out / "report.html").as_uri(), page.url]
        assert page.errors == []
    finally:
        page.close()


def test_a_report_inlines_everything_and_stays_small(runs):
    text = (runs["fit"] / "report.html").read_text()
    assert not re.search(r"""(src|href)=["'](?!data:)""", text)              # nothing loaded from elsewhere
    assert "<script src" not in text and "import(" not in text
    assert "Copyright © 2010-2026 three.js authors" in text                   # the licence travels with it
    sizes = {k: (runs[k] / "report.html").stat().st_size for k in ("fit", "images", "sequence")}
    assert all(600_000 < s < 1_500_000 for s in sizes.values()), sizes       # three.js is 0.57 MB of it


# -- the page's arrays and the helpers, without a browser ----------------------------------


def payload(page: str) -> dict:
    return json.loads(re.search(r'<script type="application/json" id="mi-loop-data">(.*?)</script>', page, re.S)[1])


def decode(a: dict) -> np.ndarray:
    """report.js's decode, in NumPy."""
    raw = base64.b64decode(a["b64"])
    q = np.frombuffer(raw, {"u4": "<u4", "f4": "<f4", "q16": "<u2", "n16": "<i2", "c8": "u1"}[a["kind"]])
    q = q.reshape(a["shape"]).astype(np.float64)
    if a["kind"] == "q16":
        return np.asarray(a["lo"]) + (np.asarray(a["hi"]) - a["lo"]) * q / 65535
    return q / {"n16": 32767, "c8": 255}.get(a["kind"], 1)


def test_the_page_carries_the_arrays_to_their_quantisation():
    Vc, Fc = datasets.icosphere(1)
    V, F, N = limit_mesh(Vc, Fc, 1)
    d = np.linspace(0, 0.02, len(V))
    data = payload(html_report.static_page("t", V, F, N, distances={"the data": d, "another": 2 * d},
                                           points=V[:10], cage=(Vc, Fc)))
    np.testing.assert_array_equal(decode(data["F"]), F.reshape(-1, 3))
    np.testing.assert_allclose(decode(data["P"]), V, atol=np.ptp(V, axis=0).max() / 65535)
    np.testing.assert_allclose(decode(data["N"]), N, atol=1 / 32767)
    assert [f["name"] for f in data["fields"]] == ["the data", "another"]
    for f, scale in zip(data["fields"], (1, 2)):
        np.testing.assert_allclose(decode(f["d"])[:, 0], scale * d, atol=scale * 0.02 / 65535)
        assert f["legend"]["max"] == scale * 0.02 and f["legend"]["top"] == pytest.approx(scale * 0.98 * 0.02)
        assert f["legend"]["title"] == f"distance to {f['name']}, % of its bounding-box diagonal"
    edges = decode(data["cage"]["E"])
    assert len(edges) == 120 and data["cage"]["n"] == 42                  # icosphere(1): 42 - 120 + 80 = 2
    assert data["creases"] is None and data["frusta"] is None and data["kind"] == "static"


def test_pages_refuse_bad_arrays_naming_what_is_wrong():
    Vc, Fc = datasets.icosphere(1)
    V, F, N = limit_mesh(Vc, Fc, 1)
    bad = F.copy()
    bad[7, 1] = len(V)
    with pytest.raises(ValueError, match=exactly(f"static_page(): expected faces with indices in [0, {len(V)}), "
                                                 f"got {bad[7].tolist()} at face 7")):
        html_report.static_page("t", V, bad, N)
    with pytest.raises(ValueError, match=re.escape("static_page(): expected N of shape (162, 3), numbers")):
        html_report.static_page("t", V, F, N[:-1])
    d = np.zeros(len(V))
    d[9] = np.nan
    with pytest.raises(ValueError, match=exactly("static_page(): expected finite distances['the data'], "
                                                 "got nan at index [9]")):
        html_report.static_page("t", V, F, N, distances={"the data": d})
    with pytest.raises(ValueError, match=exactly("static_page(): expected distances['x'] of shape (162,), numbers, "
                                                 "not empty, got shape (162, 1), dtype float64")):
        html_report.static_page("t", V, F, N, distances={"x": d[:, None]})
    with pytest.raises(ValueError, match=exactly("static_page(): expected distances as a dict: what they are to "
                                                 "(e.g. 'the data') -> array, got ndarray")):
        html_report.static_page("t", V, F, N, distances=d)
    seq = dict(names=["a", "b"], fps=24.0)
    with pytest.raises(ValueError, match=exactly("sequence_page(): expected one name per frame (2), got 1 names")):
        html_report.sequence_page("t", np.stack([V, V]), F, np.stack([N, N]), **(seq | {"names": ["a"]}))
    with pytest.raises(ValueError, match=exactly("sequence_page(): expected a frame rate fps > 0, got 0.0")):
        html_report.sequence_page("t", np.stack([V, V]), F, np.stack([N, N]), **(seq | {"fps": 0.0}))
    plots = {"frames": [0, 1], "panels": [{"title": "p", "series": {"mean": [1.0, 2.0, 3.0]}}]}
    with pytest.raises(ValueError, match=exactly("sequence_page(): expected plot values, one per frame (2), "
                                                 "got shape (3,) for 'mean'")):
        html_report.sequence_page("t", np.stack([V, V]), F, np.stack([N, N]), plots=plots, **seq)


def test_crease_curves_run_through_the_limit_tessellation_of_the_creased_mesh():
    V, F = datasets.icosphere(1)
    creases = np.array([F[0, [0, 1]], F[0, [2, 1]], F[5, [1, 2]]])         # either direction of an edge
    curves = crease_curves(V, F, creases, 2)
    assert curves.shape == (3, 5, 3)
    P, _, _ = limit_mesh(V, F, 2, creases=creases)
    from scipy.spatial import cKDTree

    gap, _ = cKDTree(P).query(curves.reshape(-1, 3))
    np.testing.assert_allclose(gap, 0, atol=1e-12)                            # points of the limit surface
    with pytest.raises(ValueError, match=exactly("crease_curves(): expected crease edges of the control faces, "
                                                 "got (0, 41) at crease 1")):
        crease_curves(V, F, np.array([F[0, [0, 1]], [0, 41]]), 2)


def test_vertex_distances_to_a_mesh_are_exact_and_to_points_ignore_the_noise():
    Vt = np.array([[0.0, 0, 0], [4, 0, 0], [0, 3, 0]])
    d = vertex_distances(np.array([[1.0, 1, 0.5], [0, 0, -1]]), ("mesh", Vt, np.array([[0, 1, 2]])))
    np.testing.assert_allclose(d, [0.1, 0.2])                                 # diagonal 5
    rng = np.random.default_rng(0)
    P = np.c_[rng.uniform(-1, 1, (4000, 2)), 0.01 * rng.standard_normal(4000)]
    P[::50, 2] += 0.5                                                          # 2 % outliers above the plane
    Q = np.c_[rng.uniform(-0.8, 0.8, (200, 2)), np.full(200, 0.05)]
    diag = np.linalg.norm(np.ptp(P, axis=0))
    d = vertex_distances(Q, ("points", P, None), N=np.tile([0.0, 0, 1], (200, 1))) * diag
    error = np.abs(d - 0.05)
    assert error.mean() < 0.004 and error.max() < 0.015, (error.mean(), error.max())  # noise 0.01: averaged out
    nearest = vertex_distances(Q, ("points", P, None)) * diag
    assert np.all(nearest >= 0.0) and np.abs(nearest - 0.05).mean() > 2 * np.abs(d - 0.05).mean()


def test_frusta_and_subsamples():
    from mi_loop.io import Camera

    c2w = np.eye(4)
    c2w[:3, 3] = [1, 2, 3]
    s = frustum_segments([Camera(c2w, 20.0, 10.0, 10.0, 5.0, 20, 10)], 4.0)
    corners = s[:4, 1]
    np.testing.assert_allclose(corners, [[-1, 4, -1], [3, 4, -1], [3, 0, -1], [-1, 0, -1]])
    np.testing.assert_allclose(s[:4, 0], np.tile([1, 2, 3], (4, 1)))
    np.testing.assert_allclose(s[4:, 0], corners)                              # the image's edges
    P = np.arange(30.0).reshape(10, 3)
    assert subsample(P, 20) is P
    picked = subsample(P, 4, seed=1)
    assert len(picked) == 4 and np.all(np.diff(picked[:, 0]) > 0) and set(picked[:, 0]) <= set(P[:, 0])
