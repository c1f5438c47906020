"""Which mask pixels the hull and the image loss believe (mi_loop.render.mask_trust), and the weighted loss.

Oracles: masks built by hand (a ramp, a subject off the frame, unseen
pixels), binary masks saved as JPEG, antialiased renders; then the weighted
loss of :class:`~mi_loop.render.images.ImageRenderer` against the same sum in
NumPy, and a silhouette that only uncertain pixels see gets no gradient.
"""
from __future__ import annotations

import io

import drjit as dr
import numpy as np
import pytest
from PIL import Image

from mi_loop.io.views import View
from mi_loop.render.cameras import rig_cameras
from mi_loop.render.captures import render_views
from mi_loop.render.images import ImageRenderer
from mi_loop.render.mask_trust import MASK_BAND, mask_votes, pixel_weights
from mi_loop.render.scene import rig_emitters

from helpers import CAMERA_BOX, as_numpy, exactly, flat, sphere_mesh


def rig(n_views, resolution=24):
    """Cameras and black-silhouette emitters of a rig around CAMERA_BOX."""
    return rig_cameras(n_views, CAMERA_BOX, resolution), rig_emitters(CAMERA_BOX, "silhouette")


def tensor(t) -> np.ndarray:
    return np.array(t, dtype=np.float64)


def disk(h=32, w=32, r=9.0, centre=(16.0, 16.0)):
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    return ((yy - centre[0]) ** 2 + (xx - centre[1]) ** 2 < r ** 2).astype(np.float32)


def test_antialiased_masks_inside_the_frame_get_no_weights():
    """A synthetic capture's masks (alpha of a render: partial coverage at the edge), at full and half size."""
    V, F = sphere_mesh(0.3, 3)
    cameras, emitters = rig(3)
    views = render_views(V, F, cameras, emitters, colors=np.zeros(V.shape), spp=16)
    for view in views + [v.resized(0.5) for v in views]:
        in_band = (view.mask >= MASK_BAND[0]) & (view.mask < MASK_BAND[1])
        assert in_band.any()                                 # edges in the band ...
        assert pixel_weights(view.mask, view.valid) is None  # ... all at the 0.5 crossing: weight 1


def test_a_soft_ramp_keeps_the_edge_and_drops_the_band_around_it():
    ramp = (np.arange(12) + 0.5) / 12                        # 0.04 .. 0.96 across 12 pixels
    mask = np.tile(ramp, (9, 1)).astype(np.float32)
    w = pixel_weights(mask, border=0)
    # crossing between pixels 5 (0.458) and 6 (0.542); band 0.2 <= m < 0.8: pixels 2..9
    np.testing.assert_array_equal(w[4], [1, 1, 0, 0, 0, 1, 1, 0, 0, 0, 1, 1])
    np.testing.assert_array_equal(w, np.tile(w[4], (9, 1)))


def jpeg(mask, quality=60):
    buffer = io.BytesIO()
    Image.fromarray(np.round(255 * mask).astype(np.uint8), "L").save(buffer, "JPEG", quality=quality)
    return np.asarray(Image.open(io.BytesIO(buffer.getvalue())), dtype=np.float32) / 255


def edge_of(mask):
    """Pixels with a 4-neighbour on the other side of 0.5 (written out again, as the oracle)."""
    fg, edge = mask >= 0.5, np.zeros(mask.shape, dtype=bool)
    edge[:, 1:] |= fg[:, 1:] != fg[:, :-1]
    edge[:, :-1] |= fg[:, 1:] != fg[:, :-1]
    edge[1:] |= fg[1:] != fg[:-1]
    edge[:-1] |= fg[1:] != fg[:-1]
    return edge


@pytest.mark.parametrize("quality, dropped", [(60, 0), (10, 10)])
def test_jpeg_ringing_off_the_edge_gets_no_weight(quality, dropped):
    """At quality 60 a binary mask rings into the band only at its edge (kept); at 10 also off it (dropped)."""
    mask = jpeg(disk(64, 64, 20.3, (32.0, 32.0)), quality)
    w = pixel_weights(mask)
    w = np.ones_like(mask) if w is None else w
    uncertain = (mask >= MASK_BAND[0]) & (mask < MASK_BAND[1])
    assert uncertain.any()
    np.testing.assert_array_equal(w[~uncertain], 1.0)
    np.testing.assert_array_equal(w[uncertain], np.where(edge_of(mask)[uncertain], 1.0, 0.0))
    assert (w == 0).sum() >= dropped


def test_the_subject_running_off_the_frame_is_not_an_outline():
    mask = disk(r=10.0, centre=(16.0, 2.0))                # cut by the left edge of the frame
    w = pixel_weights(mask)
    near = np.zeros(mask.shape, dtype=bool)
    near[:2], near[-2:], near[:, :2], near[:, -2:] = True, True, True, True
    np.testing.assert_array_equal(w == 0, near & (mask == 1))
    assert (w[:, 0] == 0).sum() == mask[:, 0].sum() > 0 and w[:, 2][mask[:, 2] == 1].min() == 1.0
    assert pixel_weights(mask, border=0) is None


def test_unseen_pixels_weigh_their_share_and_border_the_subject():
    mask = disk()
    valid = np.ones_like(mask)
    valid[:, 20:] = 0.0                                    # right of column 20: not seen (mask 0 there)
    valid[:, 19] = 0.6
    mask[:, 20:] = 0.0
    w = pixel_weights(mask, valid)
    np.testing.assert_array_equal(w[:, 20:], 0.0)
    near = mask.astype(bool) & (np.arange(32) >= 18)       # foreground within 2 pixels of column 20
    np.testing.assert_array_equal(w[near], 0.0)
    np.testing.assert_array_equal(w[~near & (valid == 1)], 1.0)
    np.testing.assert_array_equal(w[:, 19][mask[:, 19] == 0], np.float32(0.6))


@pytest.mark.parametrize("band", [(0.6, 0.9), (0.0, 0.5), (0.2, 1.2), "wide", (0.2,)])
def test_bad_bands_are_refused(band):
    message = f"mask_votes(): expected a mask band (lo, hi) with 0 < lo <= 0.5 <= hi <= 1, got {band!r}"
    with pytest.raises(ValueError, match=exactly(message)):
        mask_votes(np.zeros((2, 2)), band)


def test_bad_weight_arguments_are_refused():
    with pytest.raises(ValueError, match=exactly("pixel_weights(): expected an integer border >= 0, got -1")):
        pixel_weights(np.zeros((4, 4)), border=-1)
    with pytest.raises(ValueError, match=exactly("pixel_weights(): expected valid of the mask's shape (4, 4), "
                                                 "got shape (4, 5)")):
        pixel_weights(np.zeros((4, 4)), np.ones((4, 5)))


# -------------------------------------------------------------------------- the weighted loss


def renderer_of(masks, spp=4):
    """A 0.3-radius sphere's renderer against black photos with these masks (silhouette rig, 24x24)."""
    V, F = sphere_mesh(0.3, 1)
    cameras, emitters = rig(len(masks))
    views = [View(cam, np.zeros((24, 24, 3)), m, f"v{k}") for k, (cam, m) in enumerate(zip(cameras, masks))]
    return V, ImageRenderer(V, F, views, emitters, albedo=np.zeros(V.shape), level=2, spp=spp)


def test_the_loss_is_the_weighted_mean_of_the_pixels():
    mask = disk(24, 24, 6.0, (12.0, 12.0))
    mask[3:9, 3:9] = 0.5                                                # an uncertain patch off the edge
    V, renderer = renderer_of([mask])
    w = tensor(renderer.weights[0])
    assert w.shape == (24, 24, 3) and (w[4:8, 4:8] == 0).all() and w.sum() > 0.8 * w.size
    x = flat(V)
    loss = renderer.view_loss(x, None, 0, seed=3)[0]
    image = tensor(renderer.render(x, None, 0, seed=3))
    np.testing.assert_allclose(loss, np.mean(w * np.abs(image - tensor(renderer.targets[0]))), rtol=1e-5)


def test_a_silhouette_over_uncertain_pixels_only_gets_no_gradient():
    half = np.full((24, 24), 0.5, np.float32)                           # nothing certain anywhere
    V, renderer = renderer_of([half, half])
    assert all(w is not None and (tensor(w) == 0).all() for w in renderer.weights)
    x = flat(V, grad=True)
    losses = renderer.backward(x, None, [0, 1], seed=1)
    assert losses == [0.0, 0.0] and not as_numpy(dr.grad(x)).any()
    _, certain = renderer_of([np.zeros((24, 24), np.float32)] * 2)      # background: the sphere is pulled in
    x = flat(V, grad=True)
    assert min(certain.backward(x, None, [0, 1], seed=1)) > 0 and np.abs(as_numpy(dr.grad(x))).max() > 0
