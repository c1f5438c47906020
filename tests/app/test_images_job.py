"""``mi-loop fit-images``: a capture on disk in, a coloured control mesh, report and pictures out."""
from __future__ import annotations

import json

import numpy as np
import pytest
from matplotlib.image import imread

from mi_loop import io
from mi_loop.app.cli import main
from mi_loop.subdiv.masks import limit_mesh

from helpers import blob_capture, one_line_error

FAST = ["--init", "sphere", "--iterations", "6", "--spp", "2", "--vertices", "170", "--refinements", "1", "--quiet"]


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    return blob_capture(tmp_path_factory.mktemp("capture"))


def test_fit_images_writes_a_coloured_control_mesh_report_and_pictures(capture, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["fit-images", str(capture), "-o", str(out), *FAST]) == 0
    printed = capsys.readouterr().out.split()
    assert printed == [str(out / name) for name in ("control.ply", "limit.ply", "limit.glb", "report.json",
                                                    "report.html", "progress.png", "loss.png")]
    V, F = io.read_mesh(out / "control.ply")
    colors = io.read_vertex_colors(out / "control.ply")
    assert colors.shape == V.shape and (colors >= 0).all() and (colors <= 1).all()
    assert len(V) == 162                                 # 42 -> 162: one exact refinement within 170
    P_lim, _ = io.read_mesh(out / "limit.ply")
    assert io.read_vertex_colors(out / "limit.ply").shape == P_lim.shape
    # limit.glb: the viewer's level (2) with the albedo as linear COLOR_0, read by mi_loop's glTF reader
    from mi_loop.io.gltf import GltfFile, base_colors
    from mi_loop.subdiv.masks import limit_colors

    glb = GltfFile(out / "limit.glb", "test")
    prim = glb.doc["meshes"][0]["primitives"][0]
    P_view, F_view, _ = limit_mesh(V, F, 2)
    np.testing.assert_allclose(glb.accessor(prim["attributes"]["POSITION"]), P_view, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(glb.accessor(prim["indices"], floats=False).reshape(-1, 3), F_view)
    np.testing.assert_allclose(base_colors(glb, prim, len(P_view)), limit_colors(colors, F, 2), atol=1e-6)
    report = json.loads((out / "report.json").read_text())
    assert [s["n_vertices"] for s in report["stages"]] == [42, 162]
    assert [(s["width"], s["height"]) for s in report["stages"]] == [(20, 16), (40, 32)]
    assert len(report["views"]) == 6 and all(v["loss_end"] > 0 for v in report["views"])
    assert report["parameters"] == {"control_points": 3 * 162, "albedo": 3 * 162}
    assert report["params"]["iterations"] == 6 and report["lighting"].startswith("constant")
    grid = imread(out / "progress.png")
    assert grid.shape[:2] == (4 * 32, 4 * 40)             # target, start, fit, grey geometry rows; four views
    grey = grid[3 * 32:, :, :3]
    np.testing.assert_allclose(grey[..., 0], grey[..., 2], atol=2 / 255)   # grey: the albedo is not in it
    assert imread(out / "loss.png").shape[0] > 100


def test_fit_images_reads_the_photos_at_the_finest_stages_size(capture, tmp_path, monkeypatch):
    """--res R goes to read_capture, which decodes straight to R: the finest stage is R, the coarser R / 2."""
    from mi_loop.io import capture as capture_module

    asked = []

    def spy(path, **kwargs):
        asked.append(kwargs)
        return read_capture(path, **kwargs)

    read_capture = capture_module.read_capture
    monkeypatch.setattr(capture_module, "read_capture", spy)
    out = tmp_path / "out"
    assert main(["fit-images", str(capture), "-o", str(out), *FAST, "--res", "20", "--iterations", "2"]) == 0
    assert asked == [{"resolution": 20}]
    report = json.loads((out / "report.json").read_text())
    assert [(s["width"], s["height"]) for s in report["stages"]] == [(10, 8), (20, 16)]
    assert imread(out / "progress.png").shape[:2] == (4 * 16, 4 * 20)


def test_fit_images_reads_the_lighting_file(capture, tmp_path, capsys):
    lights = tmp_path / "lights.xml"
    lights.write_text('<scene version="3.0.0"><emitter type="constant"><rgb name="radiance" value="0.8"/>'
                      "</emitter></scene>")
    out = tmp_path / "out"
    assert main(["fit-images", str(capture), "-o", str(out), "--emitters", str(lights), *FAST]) == 0
    assert json.loads((out / "report.json").read_text())["lighting"] == str(lights)


def test_fit_images_estimates_the_lighting_and_a_gain_per_photo(capture, tmp_path):
    """--lighting sh: report.json holds the nine shading coefficients per channel and one RGB gain per photo
    (their geometric mean 1); the evaluation renders with them (the fit's loss below the start's)."""
    out = tmp_path / "out"
    assert main(["fit-images", str(capture), "-o", str(out), *FAST, "--lighting", "sh", "--highlights", "1.5"]) == 0
    report = json.loads((out / "report.json").read_text())
    lighting = report["lighting"]
    assert lighting["model"].startswith("spherical harmonics") and lighting["backdrop"].startswith("constant")
    assert np.shape(lighting["coefficients"]) == (9, 3) and np.shape(lighting["gains"]) == (6, 3)
    np.testing.assert_allclose(np.exp(np.log(lighting["gains"]).mean(axis=0)), 1.0, rtol=1e-5)
    assert np.ptp(np.array(lighting["gains"])) > 0                  # the gains moved from 1
    assert report["params"]["lighting"] == "sh" and report["params"]["highlights"] == 1.5
    losses = [(v["loss_start"], v["loss_end"]) for v in report["views"]]
    assert np.mean([e for _, e in losses]) < np.mean([s for s, _ in losses])


@pytest.mark.parametrize("extra, message", [
    (["--highlights", "-1"], "fit-images --highlights: expected a finite number >= 0, got -1.0"),
    (["--lr", "-1"], "fit-images --lr: expected a finite number > 0, got -1.0"),
    (["--refinements", "9"], "fit-images --refinements: expected an integer in 0..4, got 9"),
    (["--init", "nosuch.ply"], "fit-images --init: expected sphere, hull or an existing control mesh file, "
                               "got 'nosuch.ply'"),
])
def test_bad_options_are_refused_before_reading(extra, message, tmp_path, capsys):
    line = one_line_error(capsys, ["fit-images", str(tmp_path / "missing.json"), "-o", str(tmp_path / "o"), *extra])
    assert line == f"mi-loop: error: {message}"
    assert not (tmp_path / "o").exists()


def test_an_unknown_lighting_model_is_refused_by_the_parser(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["fit-images", str(tmp_path / "missing.json"), "-o", str(tmp_path / "o"), "--lighting", "envmap"])
    assert exit_info.value.code == 2
    assert ("mi-loop fit-images: error: argument --lighting: invalid choice: 'envmap' (choose from 'given', 'sh')"
            in capsys.readouterr().err.splitlines())
    assert not (tmp_path / "o").exists()


def test_a_lighting_file_with_a_shape_is_refused_and_nothing_is_written(capture, tmp_path, capsys):
    lights = tmp_path / "lights.xml"
    lights.write_text('<scene version="3.0.0"><emitter type="constant"/><shape type="sphere"/></scene>')
    line = one_line_error(capsys, ["fit-images", str(capture), "-o", str(tmp_path / "o"), "--emitters",
                                   str(lights), *FAST])
    assert line == (f"mi-loop: error: read_emitters(): expected only <emitter> (and <default>) elements in "
                    f"'{lights}', got <shape> as element 1 (the lighting file must not hold shapes, sensors "
                    "or integrators)")
    assert not (tmp_path / "o").exists()


def test_a_capture_with_a_missing_photo_is_refused(capture, tmp_path, capsys):
    meta = json.loads(capture.read_text())
    meta["frames"][2]["file_path"] = "images/nosuch.png"
    broken = capture.parent / "broken.json"
    broken.write_text(json.dumps(meta))
    line = one_line_error(capsys, ["fit-images", str(broken), "-o", str(tmp_path / "o"), *FAST])
    assert "frames[2].file_path" in line and "nosuch.png" in line and str(broken) in line
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("body, message", [
    ("<scene version='3.0.0'></scene>", "expected at least one <emitter> in '{p}', got none"),
    ("<scene version='3.0.0'><emitter type='nosuch'/></scene>", "expected a Mitsuba scene file in '{p}', got "),
    ("<scene", "expected well-formed XML in '{p}', got "),
    ("<emitter type='constant'/>", "expected a <scene> root element in '{p}', got <emitter>"),
])
def test_read_emitters_messages(body, message, tmp_path):
    from mi_loop.io.emitters import read_emitters

    path = tmp_path / "l.xml"
    path.write_text(body)
    with pytest.raises(ValueError) as info:
        read_emitters(path)
    assert str(info.value).startswith("read_emitters(): " + message.format(p=path))
    assert "\n" not in str(info.value)
