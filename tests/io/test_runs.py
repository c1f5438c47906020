"""The files a fit-sequence run reads back (mi_loop.io.runs) and small documents (mi_loop.io.documents):
each written by one writer and read by one reader, round trips, older runs, every refusal with its message."""
from __future__ import annotations

import json

import numpy as np
import pytest

from mi_loop.io import documents, runs
from mi_loop.io.runs import CSV_HEADER, OLDER_COLUMNS, FrameState, MetricsRow, RunRecord

from helpers import value_error


def row(frame=0, name="f", drift=(0.001, 0.002), **changes):
    values = dict(frame=frame, name=name, mean=1 / 3, rms=0.5, hausdorff=1.25, flipped_pct=0.012345,
                  drift_mean=drift[0] if drift else None, drift_p95=drift[1] if drift else None, seconds=2.0 / 3,
                  time_render=0.0, iterations=30)
    return MetricsRow(**{**values, **changes})


# -- metrics.csv ---------------------------------------------------------------------------------------------


def test_metrics_rows_round_trip_with_commas_quotes_and_empty_drift(tmp_path):
    rows = [row(0, "scan, left.ply"), row(1, 'the "best" one', drift=None), row(2, "two\nlines", drift=None)]
    path = runs.write_metrics(tmp_path / "metrics.csv", rows)
    back = runs.read_metrics(path)
    assert back == [r.rounded() for r in rows]
    assert [r.name for r in back] == ["scan, left.ply", 'the "best" one', "two\nlines"]
    assert back[1].drift_mean is None and back[1].drift_p95 is None
    assert back[0].mean == 0.333333 and back[0].flipped_pct == 0.01235 and back[0].seconds == 0.667
    assert runs.read_metrics(runs.write_metrics(tmp_path / "again.csv", back)) == back     # a fixed point
    assert (tmp_path / "again.csv").read_bytes() == path.read_bytes()


def test_metrics_csv_is_the_documented_text(tmp_path):
    """The header of CSV_HEADER, numbers at their precision, empty cells for missing drift, a quoted name."""
    path = runs.write_metrics(tmp_path / "metrics.csv", [row(0, "a"), row(1, "b, c", drift=None)])
    assert path.read_text().splitlines() == [
        CSV_HEADER,
        "0,a,0.333333,0.5,1.25,0.01235,0.001,0.002,0.667,0.000,30",
        '1,"b, c",0.333333,0.5,1.25,0.01235,,,0.667,0.000,30']
    assert CSV_HEADER == "frame,name,mean,rms,hausdorff,flipped_pct,drift_mean,drift_p95,seconds,time_render,iterations"


def test_an_empty_metrics_csv_or_a_header_alone_has_no_rows(tmp_path):
    (tmp_path / "empty.csv").write_text("")
    (tmp_path / "header.csv").write_text(CSV_HEADER + "\n")
    assert runs.read_metrics(tmp_path / "empty.csv") == []
    assert runs.read_metrics(tmp_path / "header.csv") == []


def older_run(tmp_path):
    path = tmp_path / "metrics.csv"
    path.write_text(",".join(OLDER_COLUMNS) + "\n0,seq[0],0.001,0.002,0.01,3.5,0.4,30\n")
    return path


def test_an_older_runs_metrics_are_refused_for_resume_with_the_fix(tmp_path):
    path = older_run(tmp_path)
    assert value_error(runs.read_metrics, path, "fit-sequence --resume") == (
        f"fit-sequence --resume: expected a metrics.csv with the columns {CSV_HEADER}, "
        f"got '{','.join(OLDER_COLUMNS)}' in '{path}' (a run of an older version: start it again without --resume)")


def test_an_older_runs_metrics_read_where_older_ones_are_allowed(tmp_path):
    back, = runs.read_metrics(older_run(tmp_path), older=True)
    assert (back.frame, back.name, back.mean, back.seconds, back.iterations) == (0, "seq[0]", 0.001, 3.5, 30)
    assert back.flipped_pct is None and back.drift_mean is None and back.drift_p95 is None
    assert back.cells()["flipped_pct"] == "" and back.cells()["mean"] == "0.001"


def test_metrics_refusals_name_file_line_and_column(tmp_path):
    path = tmp_path / "metrics.csv"
    assert value_error(runs.read_metrics, path, "export OUT") == (
        f"export OUT: expected a metrics.csv file, got no '{path}'")
    path.write_text("a,b,c\n1,2,3\n")
    assert value_error(runs.read_metrics, path, "export OUT", older=True) == (
        f"export OUT: expected a metrics.csv with the columns {CSV_HEADER}, got 'a,b,c' in '{path}' "
        "(not a metrics.csv of mi-loop fit-sequence)")
    path.write_text(CSV_HEADER + "\n0,a,0.1,0.2,0.3,0,,,1.0,0.0,30\n1,b,0.1,0.2\n")
    assert value_error(runs.read_metrics, path, function="read_metrics") == (
        f"expected 11 cells in every row of '{path}', got 4 in line 3")
    path.write_text(CSV_HEADER + "\n0,a,0.1,nope,0.3,0,,,1.0,0.0,30\n")
    assert value_error(runs.read_metrics, path, function="read_metrics") == (
        f"expected a number in column rms, got 'nope' in line 2 of '{path}'")
    path.write_text(CSV_HEADER + "\n0,a,0.1,0.2,0.3,0,,,1.0,0.0,3.5\n")
    assert value_error(runs.read_metrics, path, function="read_metrics") == (
        f"expected an integer in column iterations, got '3.5' in line 2 of '{path}'")


# -- state/NNNN.npz ------------------------------------------------------------------------------------------


@pytest.fixture
def state_dir(tmp_path):
    (tmp_path / "state").mkdir()
    return tmp_path


def test_the_state_file_round_trips_x_faces_rest_and_free_named_arrays(state_dir):
    rng = np.random.default_rng(0)
    x, rest = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    F = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4]], dtype=np.int32)
    extra = {"albedo": rng.random((5, 3)), "optimiser.m": rng.normal(size=(5, 3)), "optimiser.t": np.array(7)}
    path = runs.write_state(runs.state_path(state_dir, 12), FrameState(x, F, rest, extra))
    assert path == state_dir / "state" / "0012.npz"
    back = runs.read_state(path)
    np.testing.assert_array_equal(back.x, x)
    np.testing.assert_array_equal(back.rest, rest)
    np.testing.assert_array_equal(back.F, F)
    assert back.x.dtype == np.float64 and back.F.dtype == np.int64
    assert list(back.extra) == ["albedo", "optimiser.m", "optimiser.t"]           # in the order written
    for name, a in extra.items():
        np.testing.assert_array_equal(back.extra[name], a)
    assert int(back.extra["optimiser.t"]) == 7


def test_a_state_without_rest_or_extras_reads_as_such(state_dir):
    path = runs.write_state(runs.state_path(state_dir, 0), FrameState(np.zeros((3, 3)), np.array([[0, 1, 2]])))
    back = runs.read_state(path)
    assert back.rest is None and back.extra == {}
    with np.load(path) as z:
        assert z.files == ["x", "F"]


def test_state_refusals_name_the_file(state_dir):
    state = FrameState(np.zeros((3, 3)), np.array([[0, 1, 2]]), None, {"x": np.ones(3)})
    assert value_error(runs.write_state, state_dir / "a.npz", state, function="write_state") == (
        "expected extra arrays named other than x, F, rest, got ['x']")
    assert not (state_dir / "a.npz").exists()
    np.savez(state_dir / "b.npz", F=np.zeros((1, 3), int))
    assert value_error(runs.read_state, state_dir / "b.npz", function="read_state") == (
        f"expected a state file with the arrays x and F, got '{state_dir / 'b.npz'}' without x")
    (state_dir / "c.npz").write_bytes(b"not a zip")
    assert value_error(runs.read_state, state_dir / "c.npz", function="read_state").startswith(
        f"expected a state file (NPZ) of fit-sequence, got '{state_dir / 'c.npz'}': ")


# -- sequence.json -------------------------------------------------------------------------------------------


def test_the_run_record_round_trips_and_older_files_read_with_none(tmp_path):
    record = RunRecord(centre=[0.0, 1.0, 2.5], scale=3.0, lr=0.01, camera_box=[[-1, -1, -1], [1, 1, 1]],
                       options={"alpha": 0.01, "image": False}, n_frames=3, template={"source": "mesh"},
                       normals_estimated=False, images=None, emitters=None, reference=True, variant="llvm_ad_rgb",
                       fps=12.5)
    path = runs.write_run_json(tmp_path / "sequence.json", record)
    assert runs.read_run_json(path) == record
    assert list(json.loads(path.read_text())) == list(RunRecord.__dataclass_fields__)
    (tmp_path / "older.json").write_text('{"fps": 10, "retired_key": 1}')
    assert runs.read_run_json(tmp_path / "older.json") == RunRecord(fps=10)


def test_run_record_refusals(tmp_path):
    path = tmp_path / "sequence.json"
    assert value_error(runs.read_run_json, path, "fit-sequence --resume") == (
        f"fit-sequence --resume: expected the run's sequence.json next to its metrics.csv, got no '{path}'")
    path.write_text("[1, 2]")
    assert value_error(runs.read_run_json, path, function="read_run_json") == (
        f"expected the run's sequence.json next to its metrics.csv, a JSON object, got a list in '{path}'")
    path.write_text("{")
    assert value_error(runs.read_run_json, path, function="read_run_json").startswith(
        f"expected the run's sequence.json next to its metrics.csv, got '{path}': not a JSON file (")


# -- report.json, JSON documents, the package's files ---------------------------------------------------------


def test_a_fits_report_and_json_documents_are_read_with_named_failures(tmp_path):
    (tmp_path / "report.json").write_text('{"metrics": {"mean": 0.1}, "converged": true}')
    assert runs.read_report(tmp_path / "report.json")["metrics"] == {"mean": 0.1}
    (tmp_path / "list.json").write_text("[]")
    assert value_error(runs.read_report, tmp_path / "list.json", "fit-batch", function="fit-batch") == (
        f"expected a report.json of mi-loop fit, a JSON object, got a list in '{tmp_path / 'list.json'}'")
    assert value_error(documents.read_json, str(tmp_path / "nope.json"), "w", "a JSON file", function="w") == (
        f"expected a JSON file, got '{tmp_path / 'nope.json'}': no such file")
    (tmp_path / "bad.json").write_text("tcp://")
    assert value_error(documents.read_json, tmp_path / "bad.json", "w", "a JSON file", function="w") == (
        f"expected a JSON file, got '{tmp_path / 'bad.json'}': not a JSON file (Expecting value: line 1 column 1 "
        "(char 0))")


def test_the_viewer_files_are_read_from_the_package():
    script = documents.read_package_text("mi_loop.app", "viewer", "report.js")
    assert "data-drawn" in script
