"""``mi-loop fit-images`` on a real capture as published: results in the capture's own world frame.

DTU scan24 in IDR / NeuS form (``../shared/data/real/dtu_scan24``) keeps its cameras in the frame of
``world_mat`` (the scan's millimetres) and carries ``scale_mat``, the similarity that maps the unit
sphere of the normalised scene onto the object's bounding sphere. The oracle is that file's own
``scale_mat_0``: the fitted control points must lie inside its sphere, at the scale of the scan, not
in the unit sphere a fit may use inside. Read at 40 px (a small crop in time: a few seconds).
"""
from __future__ import annotations

import numpy as np
import pytest

from mi_loop import io
from mi_loop.app.cli import main

from helpers import DATA

DTU = DATA / "real" / "dtu_scan24"


@pytest.mark.slow
def test_a_dtu_fit_is_written_in_the_frame_of_world_mat(tmp_path):
    out = tmp_path / "out"
    assert main(["fit-images", str(DTU), "-o", str(out), "--res", "40", "--iterations", "2", "--vertices", "60",
                 "--refinements", "0", "--spp", "1", "--quiet"]) == 0
    V, _ = io.read_mesh(out / "control.ply")
    S = np.load(DTU / "cameras_sphere.npz")["scale_mat_0"]
    centre, radius = S[:3, 3], S[0, 0]
    assert np.linalg.norm(V - centre, axis=1).max() < 1.05 * radius
    extent = np.linalg.norm(V.max(axis=0) - V.min(axis=0))
    assert 0.3 * radius < extent < 2.1 * radius, (extent, radius)      # millimetres, not the unit sphere
