"""The jobs' inputs (mi_loop.app.inputs): templates checked against the data's frame."""
from __future__ import annotations

import numpy as np
import pytest

from mi_loop import io
from mi_loop.app.inputs import check_template_frame

from helpers import DATA, bunny_in_the_scans_frame


def test_template_frame_check_on_the_shared_bunnies():
    P, V_scan, _ = bunny_in_the_scans_frame()
    for name in ("bunny_314", "bunny_4667"):                      # none of them is in the scans' frame
        V, _ = io.read_mesh(DATA / "control" / f"{name}.ply")
        with pytest.raises(ValueError, match=r"got a template 9\.\d+x the data's size"):
            check_template_frame(V, P, "t")
    info = check_template_frame(V_scan, P, "t")                     # mapped onto the scans: accepted
    assert info["size_ratio"] == pytest.approx(1.0) and info["centre_offset"] < 1e-12
    shifted = V_scan + [0.3 * np.linalg.norm(np.ptp(P, axis=0)), 0, 0]   # 0.3 diagonals aside
    with pytest.raises(ValueError, match=r"got a template 1x the data's size whose centre is 0\.3 data diagonals"):
        check_template_frame(shifted, P, "t")
    with pytest.raises(ValueError, match=r"got a template 2\.5x"):
        check_template_frame(2.5 * (V_scan - P.mean(0)) + P.mean(0), P, "t")
