"""--no-crossing (FitOptions / SequenceOptions.no_crossing): fits whose data pass through each other do not.

The data are the surface of two overlapping balls; the templates, two balls apart. A fit follows the
data into each other (its limit surface crosses itself where the balls meet); with ``no_crossing`` no
step makes a crossing pair of the level-2 limit triangles, and the far sides still reach the data.
"""
from __future__ import annotations

import numpy as np

from mi_loop.datasets import icosphere
from mi_loop.fitting.guard import CrossingTest, hold_apart
from mi_loop.fitting.options import FitOptions
from mi_loop.fitting.static import fit
from mi_loop.subdiv.masks import limit_mesh


def _two(V, F, distance):
    """Two copies of (V, F), their centres ``distance`` apart along x."""
    return np.r_[V - [distance / 2, 0, 0], V + [distance / 2, 0, 0]], np.r_[F, F + len(V)]


def _overlapping_balls(distance: float = 0.8, radius: float = 0.5):
    """Oriented points on the union of two balls whose centres are ``distance`` apart (each ball's points
    outside the other)."""
    V, F = icosphere(4)
    P, _ = _two(radius * V, F, distance)
    N = np.r_[V, V]
    outside = np.ones(len(P), dtype=bool)
    for c in (-distance / 2, distance / 2):
        outside &= np.linalg.norm(P - [c, 0.0, 0.0], axis=1) >= radius - 1e-3
    return P[outside], N[outside]


def test_a_static_fit_with_no_crossing_stays_out_of_itself_where_the_data_overlap():
    P, N = _overlapping_balls()
    V, F = icosphere(1)
    template = _two(0.5 * V, F, 1.2)                      # 0.2 apart: no crossing at the start
    test = CrossingTest(template[1], len(template[0]))
    assert len(test.pairs(template[0])) == 0
    crossed = {}
    for no_crossing in (False, True):
        result = fit(P, N, FitOptions(no_crossing=no_crossing, iterations=60), template=template)
        crossed[no_crossing] = len(test.pairs(result.V))
        far = limit_mesh(result.V, result.F, 3)[0][:, 0]
        # the far sides fitted (measured: within 0.01 without the guard, 0.035 with it)
        np.testing.assert_allclose([far.min(), far.max()], [-0.9, 0.9], atol=0.05)
    assert crossed[False] > 0 and crossed[True] == 0


def test_hold_apart_puts_back_the_points_of_a_step_that_would_cross():
    """The second ball moved 0.4 into the first: the points of the new crossing pairs go back to where they
    were, the rest of the step stays; a step that crosses nothing is returned as it was."""
    V, F = icosphere(2)
    old, F2 = _two(V, F, 2.2)
    test = CrossingTest(F2, len(old))
    new = old.copy()
    new[len(V):, 0] -= 0.4
    assert len(test.pairs(new)) > 0
    held = hold_apart(test, old, new)
    assert len(test.pairs(held)) == 0
    back = np.all(held == old, axis=1)
    assert back[len(V):].any() and not back[len(V):].all()
    np.testing.assert_array_equal(held[~back], new[~back])
    away = old + [[0.0, 0.0, 0.1]]
    np.testing.assert_array_equal(hold_apart(test, old, away), away)


def test_a_sequence_with_no_crossing_stays_out_of_itself_in_every_frame(tmp_path, capsys):
    """Mesh frames of two balls that move into each other (0.2 apart, then touching, then 0.2 deep), from a
    template of the first frame's balls, with the coarse stage on: without --no-crossing the last frame's
    fit crosses itself, with it no frame's does, and the log says so."""
    from mi_loop.app.cli import main
    from mi_loop.io.meshes import read_mesh, write_ply

    V, F = icosphere(3)
    frames = []
    for t, distance in enumerate((1.2, 1.0, 0.8)):
        frames.append(write_ply(tmp_path / f"{t}.ply", *_two(0.5 * V, F, distance)))
    Vt, Ft = icosphere(1)
    template = write_ply(tmp_path / "template.ply", *_two(0.5 * Vt, Ft, 1.2))
    test = CrossingTest(np.r_[Ft, Ft + len(Vt)], 2 * len(Vt))
    crossed = {}
    for flags in ([], ["--no-crossing"]):
        out = tmp_path / ("on" if flags else "off")
        code = main(["fit-sequence", *map(str, frames), "-o", str(out), "--template", str(template), "--no-image",
                     "--track", "4", "--first-iterations", "40", "--iterations", "40", *flags])
        err = capsys.readouterr().err
        assert code == 0, err
        assert ("no step crosses the surface (--no-crossing)" in err) == bool(flags)
        assert "; each frame first carried by a deformation graph (--track 4)\n" in err     # mesh frames: no rays
        crossed[bool(flags)] = [len(test.pairs(read_mesh(out / "control" / f"{t:04d}.ply")[0])) for t in range(3)]
    assert crossed[False][-1] > 0
    assert crossed[True] == [0, 0, 0]

