"""Pieces of the capture-grade sequence fit: data support, facing-only IMLS and coverage, photo renderer reuse."""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from mi_loop.energies.coverage import Coverage
from mi_loop.energies.imls import IMLS
from mi_loop.fitting.sequence import support


def slab(n=21, gap=0.1):
    """Points on the plane z = 0 with normals +z (the near side of a slab whose far side z = -gap is unseen)."""
    g = np.linspace(-1, 1, n)
    P = np.stack(np.meshgrid(g, g, [0.0]), -1).reshape(-1, 3)
    return P, np.tile([0.0, 0.0, 1.0], (len(P), 1))


def test_support_is_one_near_facing_points_and_zero_on_the_far_side():
    P, N = slab()
    tree = cKDTree(P)
    Q = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -0.1], [0.0, 0.0, -0.1], [0.0, 0.0, 2.0]])
    Nq = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])
    s = support(Q, tree, 0.1, Nq, N)
    assert s.tolist() == [1.0, 1.0, 0.0, 0.0]               # the far side faces away: unsupported
    assert support(Q, tree, 0.1)[2] == 1.0                  # without normals it would count as seen


def test_imls_with_sample_normals_ignores_points_facing_the_other_way():
    P, N = slab()
    imls = IMLS(P, N, h0=0.3)
    Q = np.array([[0.0, 0.0, -0.1], [0.0, 0.0, 0.05]])
    imls.update(Q)
    assert imls.valid[0].any()                              # the far side is pulled onto the near one ...
    imls.update(Q, normals=np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]]))
    assert not imls.valid[0].any() and imls.valid[1].any()  # ... unless it faces away from the points
    assert imls.n_isolated == 1


def test_coverage_with_sample_normals_pulls_the_nearest_facing_sample():
    P, N = slab(5)
    Q = np.array([[0.0, 0.0, -0.01], [0.0, 0.0, 0.2]])     # a far-side sample nearer than the near-side one
    cover = Coverage(P, N)
    cover.update(Q)
    assert set(cover.nearest.tolist()) == {0}
    cover.update(Q, normals=np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]]))
    assert set(cover.nearest.tolist()) == {1}


def test_the_photo_renderer_takes_new_photos_from_the_same_cameras_only():
    from mi_loop import datasets
    from mi_loop.io.emitters import DEFAULT_EMITTERS
    from mi_loop.render.cameras import fibonacci_cameras
    from mi_loop.render.photo import PhotoRenderer, render_views

    V, F = datasets.icosphere(1)
    lights = [dict(e) for e in DEFAULT_EMITTERS]
    cams = fibonacci_cameras(2, [0, 0, 0], 3.0, fov_x_deg=40, width=16, height=16)
    a = render_views(0.5 * V, F, cams, lights, spp=4)
    b = render_views(0.7 * V, F, cams, lights, spp=4)
    r = PhotoRenderer(V, F, np.full(V.shape, 0.5), a, lights, level=0, spp=2)
    before = np.array(r.targets[0])
    assert r.set_photos(b)
    assert not np.allclose(np.array(r.targets[0]), before)
    other = render_views(0.7 * V, F, fibonacci_cameras(2, [0, 0, 0], 4.0, fov_x_deg=40, width=16, height=16),
                         lights, spp=4)
    assert not r.set_photos(other)
