"""Fitting one frame of a sequence (mi_loop.fitting.sequence.fit_frame): geometric and image terms.

The job around it (``mi-loop fit-sequence``: frames, outputs, resume) is tested
in tests/app/test_sequence_job.py, the renderer in tests/render/test_images.py.
"""
from __future__ import annotations

import numpy as np
import pytest

from mi_loop.ad.operator import LimitOperator
from mi_loop.fitting.options import SequenceOptions
from mi_loop.fitting.sequence import Rig, fit_frame
from mi_loop.fitting.static import sample_parameters
from mi_loop.mesh.geometry import mean_edge_length
from mi_loop.mesh.sampling import sample_surface

from helpers import CAMERA_BOX, limit_surface, sphere_mesh


def limit_radius(V, F, level=2):
    """Mean distance to the origin of a level-``level`` tessellation of the limit surface."""
    return float(np.linalg.norm(limit_surface(V, F, level)[0], axis=1).mean())


def test_fit_frame_geometric_terms_pull_a_small_sphere_onto_the_target():
    """Start: control sphere of radius 0.4 (limit ~0.36); target: points on a 0.5 sphere."""
    V0, F = sphere_mesh(0.4, 1)
    Vt, Ft = sphere_mesh(0.5, 3)
    P, N, _ = sample_surface(Vt, Ft, 3000, seed=0)
    options = SequenceOptions(image=False, iterations=60)
    op = LimitOperator(F, len(V0), *sample_parameters(F, len(V0), "vertices"), derivatives=False)
    before = abs(limit_radius(V0, F) - 0.5)
    V, info = fit_frame(V0, F, P, N, op, None, options, frame=0, lr=0.02 * mean_edge_length(V0, F))
    after = abs(limit_radius(V, F) - 0.5)
    assert before > 0.1
    assert after < 0.1 * before, (before, after)
    assert info["iterations"] == 60 and info["time_render"] == 0.0
    assert np.isnan(info["history"]["image"]).all()
    assert info["history"]["geo"][-1] < 0.1 * info["history"]["geo"][0]
    assert V.shape == V0.shape and np.isfinite(V).all()


@pytest.mark.parametrize("name, mesh_default, points_default, fixed", [("cover", 3.0, 0.3, {}),
                                                                        ("fold", 0.01, 1.0, {"cover": 3.0})])
def test_the_coverage_and_fold_weights_default_by_the_kind_of_frame(name, mesh_default, points_default, fixed):
    """None gives the same fit as the weight of the frame's kind given explicitly, and not the other kind's.

    The fold case fixes the coverage weight: the coverage pulls the surface into the dent, where the
    normals turn by more than 60 degrees and the barrier acts."""
    V0, F = sphere_mesh(0.4, 2)
    Vt, Ft = sphere_mesh(0.5, 4)
    u = Vt / np.linalg.norm(Vt, axis=1, keepdims=True)
    Vt = u * (0.5 - 0.35 * np.exp(-((1 - u[:, 2]) / 0.2) ** 2))[:, None]     # a deep dent: its walls turn normals
    P, N, _ = sample_surface(Vt, Ft, 4000, seed=0)
    op = LimitOperator(F, len(V0), *sample_parameters(F, len(V0), "level1"), derivatives=True)

    def fit(mesh_frame, weight=None):
        options = SequenceOptions(image=False, iterations=60, **fixed, **{name: weight})
        return fit_frame(V0, F, P, N, op, None, options, frame=0, lr=0.02 * mean_edge_length(V0, F),
                         complete=mesh_frame)[0]

    for mesh_frame, own, other in ((True, mesh_default, points_default), (False, points_default, mesh_default)):
        default = fit(mesh_frame)
        assert np.array_equal(default, fit(mesh_frame, own)), mesh_frame
        assert np.abs(default - fit(mesh_frame, other)).max() > 1e-3, mesh_frame
    weight = getattr(SequenceOptions(**{name: 0.5}), f"{name}_weight")        # given: every frame's
    assert weight(mesh_frame=False) == weight(mesh_frame=True) == 0.5
    if name == "cover":                                                     # photos keep the mesh frames' weight
        assert SequenceOptions().cover_weight(mesh_frame=False, photos=True) == 3.0
        assert SequenceOptions(cover=0.5).cover_weight(mesh_frame=False, photos=True) == 0.5


def test_fit_frame_image_only_grows_towards_a_larger_silhouette():
    """geometric=False: silhouettes of a 0.45 sphere grow a 0.3 control sphere (limit ~0.27)."""
    V0, F = sphere_mesh(0.3, 1)
    options = SequenceOptions(views=4, views_per_iteration=2, resolution=24, spp=4, target_spp=16,
                              level=1, mode="silhouette", geometric=False, iterations=20, image_every=1)
    Vt, Ft = sphere_mesh(0.45)
    images = Rig(options, CAMERA_BOX).images(V0, F, (Vt, Ft), 0)
    op = LimitOperator(F, len(V0), *sample_parameters(F, len(V0), "vertices"), derivatives=False)
    V, info = fit_frame(V0, F, None, None, op, images, options, frame=0, lr=0.01)
    r0, r1 = limit_radius(V0, F), limit_radius(V, F)
    assert r1 > r0 + 0.03, (r0, r1)
    assert r1 < 0.45 + 0.05, r1                                  # does not overshoot the target
    assert info["iterations"] == 20 and info["time_render"] > 0
    image = np.array(info["history"]["image"])
    assert np.isfinite(image).all() and image[-5:].mean() < image[:5].mean()
