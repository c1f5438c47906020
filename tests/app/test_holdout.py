"""``mi-loop fit-images --holdout K``: photos left out of the fit, and the fit scored on them.

Analytic oracles for the scores first (two offset squares, a constant error),
then the job on a tiny synthetic capture: the held-out photos never reach the
fit, ``report.json`` scores each one, and the scores agree with those measured
independently on the written ``holdout.png``.
"""
from __future__ import annotations

import json

import numpy as np
import pytest
from matplotlib.image import imread

from mi_loop.app.cli import main
from mi_loop.fitting.holdout import masked_psnr, silhouette_iou, split_views

from helpers import blob_capture, one_line_error

FAST = ["--init", "sphere", "--iterations", "6", "--spp", "2", "--vertices", "170", "--refinements", "1", "--quiet"]


# -- the split and the scores ------------------------------------------------------------


def test_every_kth_photo_is_held_out_and_the_first_is_always_fitted():
    assert split_views(6, 3) == ([0, 1, 3, 4], [2, 5])
    assert split_views(5, 2) == ([0, 2, 4], [1, 3])
    assert split_views(5, 5) == ([0, 1, 2, 3], [4])
    assert split_views(3, 0) == ([0, 1, 2], [])


@pytest.mark.parametrize("n, k, message", [
    (6, 1, "expected a holdout K of 0 (off) or an integer >= 2 (K = 1 would hold out every photo), got 1"),
    (6, -2, "expected a holdout K of 0 (off) or an integer >= 2 (K = 1 would hold out every photo), got -2"),
    (6, 2.0, "expected a holdout K of 0 (off) or an integer >= 2 (K = 1 would hold out every photo), got 2.0"),
    (6, 7, "expected a holdout K of at most the 6 photos (a larger K holds none out), got 7"),
    (2, 2, "expected a holdout K that leaves at least two of the 2 photos to fit, got K = 2, which leaves 1"),
])
def test_split_views_refuses_a_k_that_leaves_nothing_to_fit_or_to_score(n, k, message):
    with pytest.raises(ValueError) as info:
        split_views(n, k)
    assert str(info.value) == f"split_views(): {message}"


def test_iou_of_two_offset_squares():
    """10x10 squares offset by (3, 4): overlap 7x6 = 42, union 200 - 42 = 158."""
    a, b = np.zeros((30, 30)), np.zeros((30, 30))
    a[5:15, 5:15] = 1.0
    b[8:18, 9:19] = 0.8                                  # >= 0.5: inside
    b[0, 0] = 0.49                                       # < 0.5: outside
    assert silhouette_iou(a, b) == 42 / 158
    assert silhouette_iou(a, a) == 1.0 and silhouette_iou(a, 1 - a) == 0.0
    valid = np.ones((30, 30))
    valid[:, 15:] = 0.2                                  # unseen: columns 15.. leave the score
    assert silhouette_iou(a, b, valid) == 42 / (100 + 10 * 6 - 42)   # b keeps columns 9..14
    assert np.isnan(silhouette_iou(np.zeros((3, 3)), np.zeros((3, 3))))


def test_psnr_inside_the_mask_of_a_known_error():
    """An error of 0.1 inside the mask: MSE 0.01, PSNR 20 dB; outside anything goes; values clipped to [0, 1]."""
    photo = np.full((8, 8, 3), 0.5)
    mask = np.zeros((8, 8))
    mask[2:6, 2:6] = 1.0
    render = photo + 0.1
    render[mask < 0.5] = 7.0                             # outside the mask: not scored
    np.testing.assert_allclose(masked_psnr(render, photo, mask), 20.0, rtol=0, atol=1e-12)
    valid = np.ones((8, 8))
    valid[2:4] = 0.0                                     # rows 2-3 unseen
    render[4:6, 2:6] = 0.5 + 0.01                        # the rest: an error of 0.01, 40 dB
    np.testing.assert_allclose(masked_psnr(render, photo, mask, valid), 40.0, rtol=0, atol=1e-9)
    np.testing.assert_allclose(masked_psnr(np.full((1, 1, 3), 2.0), np.full((1, 1, 3), 0.9), np.ones((1, 1))),
                               20.0, rtol=0, atol=1e-12)       # 2.0 clipped to 1
    assert masked_psnr(photo, photo, mask) == np.inf
    assert np.isnan(masked_psnr(render, photo, np.zeros((8, 8))))


@pytest.mark.parametrize("call, message", [
    (lambda: silhouette_iou(np.zeros((3, 3)), np.zeros((3, 4))),
     "silhouette_iou(): expected two masks of one shape (h, w), got shapes (3, 3) and (3, 4)"),
    (lambda: silhouette_iou(np.zeros((3, 3)), np.zeros((3, 3)), np.ones((2, 2))),
     "silhouette_iou(): expected valid of the masks' shape (3, 3), got shape (2, 2)"),
    (lambda: masked_psnr(np.zeros((3, 3, 3)), np.zeros((3, 3, 3)), np.ones((3, 2))),
     "masked_psnr(): expected images of shape (h, w, 3) and a mask of shape (h, w), got shapes (3, 3, 3), "
     "(3, 3, 3) and (3, 2)"),
])
def test_score_shape_errors(call, message):
    with pytest.raises(ValueError) as info:
        call()
    assert str(info.value) == message


# -- the job -------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    return blob_capture(tmp_path_factory.mktemp("capture"))


@pytest.fixture(scope="module")
def held_out(capture, tmp_path_factory):
    """``fit-images --holdout 3`` of the capture: its OUTDIR and the views fit_images was given."""
    from mi_loop.fitting import images

    given, fit_images = [], images.fit_images

    def spy(views, *args, **kwargs):
        given.append([v.name for v in views])
        return fit_images(views, *args, **kwargs)

    patch = pytest.MonkeyPatch()
    patch.setattr(images, "fit_images", spy)
    out = tmp_path_factory.mktemp("holdout") / "out"
    try:
        assert main(["fit-images", str(capture), "-o", str(out), *FAST, "--holdout", "3"]) == 0
    finally:
        patch.undo()
    return out, given


def test_held_out_photos_are_left_out_of_the_fit_and_scored(capture, held_out):
    out, given = held_out
    names = [f["file_path"] for f in json.loads(capture.read_text())["frames"]]
    assert given == [[names[i] for i in (0, 1, 3, 4)]]
    report = json.loads((out / "report.json").read_text())
    assert [v["name"] for v in report["views"]] == given[0]
    held = report["holdout"]
    assert held["k"] == 3 and held["rule"] == "photos i with i % k == k - 1"
    assert [(v["index"], v["name"]) for v in held["views"]] == [(2, names[2]), (5, names[5])]
    iou, psnr = [v["iou"] for v in held["views"]], [v["psnr_db"] for v in held["views"]]
    assert all(0.5 < x <= 1 for x in iou) and all(10 < x < 60 for x in psnr)
    np.testing.assert_allclose([held["iou_mean"], held["iou_median"]], [np.mean(iou), np.median(iou)], rtol=1e-12)
    np.testing.assert_allclose([held["psnr_mean_db"], held["psnr_median_db"]], [np.mean(psnr), np.median(psnr)],
                               rtol=1e-12)
    assert report["params"]["holdout"] == 3
    page = (out / "report.html").read_text()
    assert "held-out photos: silhouette IoU, PSNR" in page and "2 photos held out of the fit (--holdout 3)" in page


def test_the_scores_agree_with_holdout_png(held_out):
    """Measured again on the written picture: rows photo, render, silhouettes (white both, red photo, blue render)."""
    out, _ = held_out
    held = json.loads((out / "report.json").read_text())["holdout"]["views"]
    grid = imread(out / "holdout.png")[..., :3].astype(np.float64)
    assert grid.shape == (3 * 32, 2 * 40, 3)
    for j, view in enumerate(held):
        photo, render, agree = (grid[r * 32:(r + 1) * 32, j * 40:(j + 1) * 40] for r in range(3))
        in_photo = agree[..., 0] > 0.75                  # white or red
        in_render = agree[..., 2] > 0.75                 # white or blue
        both = in_photo & in_render
        assert view["iou"] == both.sum() / (in_photo | in_render).sum()
        mse = np.mean((photo[in_photo] - render[in_photo]) ** 2)     # sRGB, 8 bits
        np.testing.assert_allclose(view["psnr_db"], 10 * np.log10(1 / mse), rtol=0, atol=0.05)


def test_holdout_summary_line(capture, tmp_path, capsys):
    out = tmp_path / "out"
    argv = [a for a in FAST if a != "--quiet"]
    assert main(["fit-images", str(capture), "-o", str(out), *argv, "--iterations", "2", "--holdout", "2"]) == 0
    err = capsys.readouterr().err
    held = json.loads((out / "report.json").read_text())["holdout"]
    assert [v["index"] for v in held["views"]] == [1, 3, 5]
    assert (f"held out 3 views: IoU median {held['iou_median']:.3f}, PSNR median {held['psnr_median_db']:.2f} dB"
            in err)
    assert (out / "holdout.png").exists()


@pytest.mark.parametrize("k, frames, message", [
    ("1", 6, "fit-images --holdout: expected 0 (off) or an integer >= 2, got 1"),
    ("-1", 6, "fit-images --holdout: expected 0 (off) or an integer >= 2, got -1"),
    ("7", 6, "fit-images --holdout: expected a holdout K of at most the 6 photos (a larger K holds none out), "
             "got 7 ({capture})"),
    ("2", 2, "fit-images --holdout: expected a holdout K that leaves at least two of the 2 photos to fit, "
             "got K = 2, which leaves 1 ({capture})"),
])
def test_bad_holdout_is_refused_and_nothing_is_written(capture, k, frames, message, tmp_path, capsys):
    meta = json.loads(capture.read_text())
    meta["frames"] = meta["frames"][:frames]
    cut = capture.parent / f"first_{frames}.json"
    cut.write_text(json.dumps(meta))
    line = one_line_error(capsys, ["fit-images", str(cut), "-o", str(tmp_path / "o"), *FAST, "--holdout", k])
    assert line == "mi-loop: error: " + message.format(capture=cut)
    assert not (tmp_path / "o").exists()
