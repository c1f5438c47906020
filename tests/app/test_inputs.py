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


def test_frame_reader_gives_fitting_frames_by_name(tmp_path):
    """A mesh frame: points sampled on it (seed + t) and the mesh kept; a point cloud without normals: its own
    points with estimated unit normals, no mesh, and the reader says so once."""
    from mi_loop import datasets
    from mi_loop.app.inputs import FitFrame, FrameReader
    from mi_loop.app.progress import Reporter
    from mi_loop.mesh.sampling import sample_surface

    V, F = datasets.icosphere(2)
    io.write_ply(tmp_path / "0000.ply", V, F)
    np.savetxt(tmp_path / "0001.xyz", 1.1 * V)
    reader = FrameReader(io.read_frames([tmp_path]), n_points=500, seed=3, log=Reporter(quiet=True))
    mesh, cloud = reader(0), reader(1)
    assert isinstance(mesh, FitFrame) and mesh.name == "0000.ply" and mesh.P.shape == (500, 3)
    np.testing.assert_array_equal(mesh.P, sample_surface(V, F, 500, seed=3)[0])
    np.testing.assert_array_equal(mesh.mesh[0], V)
    np.testing.assert_array_equal(mesh.mesh[1], F)
    assert cloud.name == "0001.xyz" and cloud.mesh is None and reader.normals_estimated
    np.testing.assert_allclose(cloud.P, 1.1 * V)
    np.testing.assert_allclose(np.linalg.norm(cloud.N, axis=1), 1.0)
    kind, P, N = reader.target(1)
    assert kind == "points" and N is not None
    np.testing.assert_allclose(P, 1.1 * V)


def test_frame_reader_refuses_a_frame_with_nan_and_names_it(tmp_path):
    from mi_loop import datasets
    from mi_loop.app.inputs import FrameReader
    from mi_loop.app.progress import Reporter

    V, F = datasets.icosphere(1)
    Vs = np.stack([V, V])
    Vs[1, 5, 2] = np.nan
    np.savez(tmp_path / "seq.npz", vertices=Vs, faces=F)
    reader = FrameReader(io.read_frames([tmp_path / "seq.npz"]), n_points=100, seed=0, log=Reporter(quiet=True))
    assert reader(0).name == "seq[0]"
    with pytest.raises(ValueError) as info:
        reader(1)
    assert str(info.value) == (f"fit-sequence FRAMES: expected finite coordinates in frame seq[1], got vertex 5 = "
                               f"{Vs[1, 5].tolist()}")
