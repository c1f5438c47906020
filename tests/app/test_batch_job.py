"""``mi-loop fit-batch`` (mi_loop.app.batch_job, batch_summary, cluster): outputs, failures, reruns, clusters.

Fits are tiny on purpose (600-point spheres, :data:`FAST`: 30 control
vertices, 5 iterations). One batch of two good inputs and an unreadable one
runs on its own local cluster as a user starts it (:func:`first_run`); the
reruns, the sequences and the scheduler tests share a cluster started here
(:func:`cluster`). Every rejection is checked before anything runs.
"""
from __future__ import annotations

import csv
import importlib.util
import json
import logging
import shutil
import socket

import numpy as np
import pytest

import mi_loop.io
from mi_loop import datasets, io
from mi_loop.app import batch_job, batch_summary
from mi_loop.app import cluster as cluster_module
from mi_loop.app.batch_job import Task, fit_task
from mi_loop.app.batch_summary import COLUMNS, FIT_METRICS, SEQUENCE_METRICS
from mi_loop.app.cli import main
from mi_loop.app.fit_job import OUTPUTS
from mi_loop.app.parser import build_parser
from mi_loop.fitting.options import FitOptions
from mi_loop.io.points import POINT_SUFFIXES

from helpers import one_line_error, run_console, sphere_points, write_xyz

#: Options of a quick fit.
FAST = ["--vertices", "30", "--iterations", "5"]
FILES = f"point-cloud or mesh files ({' '.join(POINT_SUFFIXES)}; directories only with --sequences)"
SEQUENCES = "sequences: directories of frames or NPZ files (vertices (T, V, 3), faces)"
SCHEDULER = "a scheduler address tcp://host:port or the JSON file that `dask scheduler --scheduler-file` writes"


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """``a.xyz`` and ``b.xyz`` (noisy spheres, 600 points) and ``bad.ply`` (not a PLY file)."""
    root = tmp_path_factory.mktemp("inputs")
    write_xyz(root / "a.xyz", *sphere_points(600, noise=0.01, seed=1))
    write_xyz(root / "b.xyz", *sphere_points(600, radius=0.7, noise=0.01, seed=2))
    (root / "bad.ply").write_text("not a ply file\n")
    return root


@pytest.fixture(scope="module")
def first_run(inputs, tmp_path_factory):
    """``mi-loop fit-batch a.xyz b.xyz bad.ply`` from the console script, on its own local cluster."""
    out = tmp_path_factory.mktemp("first") / "out"
    result = run_console("fit-batch", *(str(inputs / n) for n in ("a.xyz", "b.xyz", "bad.ply")), "-o", str(out),
                         "--workers", "2", *FAST, timeout=240)
    return out, result


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """A local Dask cluster of two worker processes that also writes its scheduler file."""
    from distributed import LocalCluster

    path = tmp_path_factory.mktemp("scheduler") / "scheduler.json"
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                      silence_logs=logging.ERROR, scheduler_kwargs={"scheduler_file": str(path)}) as c:
        c.scheduler_file_path = path
        yield c


def read_summary(out):
    """``out/summary.csv``: the header and the rows as dicts."""
    with open(out / "summary.csv", newline="") as f:
        reader = csv.DictReader(f)
        return reader.fieldnames, list(reader)


# -- a batch with a failing input ----------------------------------------------------


def test_a_batch_fits_every_input_and_records_the_failed_one(first_run):
    out, result = first_run
    assert result.returncode == 1, result.stderr
    errors = [line for line in result.stderr.splitlines() if line.startswith("mi-loop: ")]
    assert errors == [f"mi-loop: error: fit-batch: 1 of 3 inputs failed (bad); their errors are in "
                      f"{out / 'summary.csv'}"], result.stderr
    assert "Traceback" not in result.stderr and "malloc" not in result.stderr
    assert sorted(result.stdout.split()[:2]) == [str(out / "a"), str(out / "b")]     # as each one is done
    assert result.stdout.split()[2:] == [str(out / "summary.csv"), str(out / "report.html")]
    assert sorted(p.name for p in out.iterdir()) == ["a", "b", "report.html", "summary.csv"]   # no bad/, no staging
    for name in ("a", "b"):
        assert sorted(p.name for p in (out / name).iterdir()) == sorted(OUTPUTS)
    assert "starting a local Dask cluster: 2 worker processes, one thread each" in result.stderr
    assert "a: done after " in result.stderr and "bad: failed after " in result.stderr
    dashboard = importlib.util.find_spec("bokeh") is not None        # bokeh is not a dependency
    assert ("Dask dashboard: http" in result.stderr) == dashboard


def test_the_summary_has_a_row_per_input_with_its_worker_error_and_metrics(first_run, inputs):
    out, _ = first_run
    header, rows = read_summary(out)
    assert header == [*COLUMNS, *FIT_METRICS]
    assert {"flipped_area_pct", "self_intersecting_pct"} <= set(header)          # the folds of every fit too
    assert [r["input"] for r in rows] == [str(inputs / n) for n in ("a.xyz", "b.xyz", "bad.ply")]
    assert [r["status"] for r in rows] == ["done", "done", "failed"]
    assert all(r["worker"].startswith("tcp://") for r in rows)
    assert float(rows[0]["seconds"]) > 0.5 and float(rows[1]["seconds"]) > 0.5 and float(rows[2]["seconds"]) >= 0
    assert rows[2]["error"].startswith(f"load_oriented_points(): expected a PLY file (a header from 'ply' to "
                                       f"'end_header') in '{inputs / 'bad.ply'}', got a file starting")
    assert rows[2]["mean"] == "" and rows[0]["error"] == ""
    for row, name in zip(rows[:2], "ab"):
        report = json.loads((out / name / "report.json").read_text())
        for key in FIT_METRICS[:-2]:
            assert float(row[key]) == report["metrics"][key], key
        assert int(row["iterations"]) == report["params"]["iterations_run"] == 5
        assert row["converged"] == str(report["converged"])


def test_a_batch_fit_equals_mi_loop_fit_bit_for_bit(first_run, inputs, tmp_path, capsys):
    out, _ = first_run
    assert main(["fit", str(inputs / "a.xyz"), "-o", str(tmp_path / "fit"), *FAST, "--quiet"]) == 0
    for name in ("control.ply", "limit.ply", "limit.glb"):
        assert (out / "a" / name).read_bytes() == (tmp_path / "fit" / name).read_bytes(), name


def test_a_rerun_skips_the_complete_inputs_and_fits_the_failed_one_again(first_run, inputs, cluster, tmp_path,
                                                                         capsys, monkeypatch):
    written = []                                       # the statuses in summary.csv each time it is written

    def write_summary(path, names, rows, sequence):
        written.append([rows[n]["status"] for n in names if n in rows])
        return batch_summary.write_summary(path, names, rows, sequence)

    monkeypatch.setattr(batch_job, "write_summary", write_summary)
    out = tmp_path / "out"
    shutil.copytree(first_run[0], out)
    before = {n: (out / n / "control.ply").stat().st_mtime_ns for n in "ab"}
    write_xyz(tmp_path / "bad.xyz", *sphere_points(600, radius=1.2, noise=0.01, seed=3))
    monkeypatch.chdir(tmp_path)                        # a relative input; the workers run elsewhere
    argv = ["fit-batch", str(inputs / "a.xyz"), str(inputs / "b.xyz"), "bad.xyz", "-o", str(out),
            "--scheduler", cluster.scheduler_address, *FAST]
    code = main(argv)
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "3 inputs: 1 to fit, 2 complete already (skipped)" in captured.err
    assert f"connected to the Dask scheduler {cluster.scheduler_address}: 2 workers" in captured.err
    assert captured.out.split() == [str(out / "bad"), str(out / "summary.csv"), str(out / "report.html")]
    _, rows = read_summary(out)
    assert [(r["input"], r["status"]) for r in rows] == [(str(inputs / "a.xyz"), "skipped"),
                                                         (str(inputs / "b.xyz"), "skipped"), ("bad.xyz", "done")]
    assert rows[2]["worker"] in cluster.scheduler_info["workers"]
    assert rows[0]["mean"] == read_summary(first_run[0])[1][0]["mean"]        # skipped rows keep their metrics
    assert {n: (out / n / "control.ply").stat().st_mtime_ns for n in "ab"} == before
    assert sorted(p.name for p in (out / "bad").iterdir()) == sorted(OUTPUTS)
    assert json.loads((out / "bad" / "report.json").read_text())["input"] == str(tmp_path / "bad.xyz")
    assert written == [["skipped", "skipped"], ["skipped", "skipped", "done"]]   # before, then as each finishes
    assert main(argv) == 0                                                     # all complete: nothing runs
    err = capsys.readouterr().err
    assert "3 inputs: 0 to fit, 3 complete already (skipped)" in err and "Dask" not in err
    assert [r["status"] for r in read_summary(out)[1]] == ["skipped"] * 3


def test_a_failed_fit_leaves_no_output_directory(inputs, tmp_path, monkeypatch):
    def broken(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(mi_loop.io, "write_png", broken)       # after control.ply and limit.ply are staged
    options = FitOptions(n_vertices=30, iterations=5)
    row = fit_task(Task(inputs / "a.xyz", tmp_path / "a", options, {"variant": "llvm_ad_rgb"}))
    assert (row["status"], row["error"], row["worker"]) == ("failed", "disk full", "local")
    assert list(tmp_path.iterdir()) == []


# -- sequences -----------------------------------------------------------------------


@pytest.mark.slow
def test_a_batch_of_sequences_fits_each_like_fit_sequence(cluster, tmp_path, capsys):
    V, F = datasets.icosphere(2)
    np.savez(tmp_path / "grow.npz", vertices=np.stack([V * (1 + 0.1 * t) for t in range(2)]), faces=F)
    (tmp_path / "walk").mkdir()
    for t in range(2):
        io.write_ply(tmp_path / "walk" / f"{t}.ply", V + [0.05 * t, 0, 0], F)
    io.write_ply(tmp_path / "control.ply", *datasets.icosphere(1))
    out = tmp_path / "out"
    code = main(["fit-batch", "--sequences", str(tmp_path / "*.npz"), str(tmp_path / "walk"), "-o", str(out),
                 "--scheduler", str(cluster.scheduler_file_path), "--template", str(tmp_path / "control.ply"),
                 "--no-image", "--iterations", "4", "--first-iterations", "4", "--points", "500", "--quiet"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    header, rows = read_summary(out)
    assert header == [*COLUMNS, *SEQUENCE_METRICS]
    assert [(r["input"], r["status"], r["frames"]) for r in rows] == [
        (str(tmp_path / "grow.npz"), "done", "2"), (str(tmp_path / "walk"), "done", "2")]
    assert [r["last_frame"] for r in rows] == ["grow[1]", "1.ply"]
    for row, name in zip(rows, ("grow", "walk")):
        with open(out / name / "metrics.csv", newline="") as f:
            last = list(csv.DictReader(f))[-1]
        assert [row[k] for k in SEQUENCE_METRICS[2:]] == [last[k] for k in SEQUENCE_METRICS[2:]]
        assert sorted(p.name for p in (out / name / "control").iterdir()) == ["0000.ply", "0001.ply"]


# -- where it runs -------------------------------------------------------------------


def test_a_scheduler_file_gives_the_schedulers_address(cluster):
    assert cluster_module.scheduler_address(str(cluster.scheduler_file_path)) == cluster.scheduler_address


def test_an_unreachable_scheduler_is_refused_and_writes_nothing(inputs, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(cluster_module, "CONNECT_TIMEOUT", 1.0)
    with socket.socket() as s:                       # a port that nothing listens on
        s.bind(("127.0.0.1", 0))
        address = f"tcp://127.0.0.1:{s.getsockname()[1]}"
    out = tmp_path / "new" / "out"
    line = one_line_error(capsys, ["fit-batch", str(inputs / "a.xyz"), "-o", str(out), "--scheduler", address])
    assert line.startswith(f"mi-loop: error: fit-batch --scheduler: expected a running Dask scheduler, got "
                           f"'{address}': Timed out trying to connect"), line
    assert not (tmp_path / "new").exists()


# -- rejected before anything runs ---------------------------------------------------


def _scheduler_file(tmp_path, text):
    path = tmp_path / "sched.json"
    path.write_text(text)
    return path


REJECTED = {
    "duplicate names": (lambda d, t: [str(d / "a.xyz"), str(_copy(d / "a.xyz", t / "other" / "a.ply"))],
                        "fit-batch INPUTS: expected inputs of distinct names (each is fitted into OUTDIR/<name>/), "
                        "got '{d}/a.xyz' and '{t}/other/a.ply', both named 'a'"),
    "missing input": (lambda d, t: [str(d / "a.xyz"), str(t / "nope.ply")],
                      "fit-batch INPUTS: expected existing files or directories, or quoted glob patterns, "
                      "got '{t}/nope.ply': no such file or directory"),
    "pattern of nothing": (lambda d, t: [str(t / "*.ply")],
                           f"fit-batch INPUTS: expected {FILES} matching the pattern, got none for '{{t}}/*.ply'"),
    "directory": (lambda d, t: [str(d)], f"fit-batch INPUTS: expected {FILES}, got '{{d}}'"),
    "file as a sequence": (lambda d, t: ["--sequences", str(d / "a.xyz")],
                           f"fit-batch INPUTS: expected {SEQUENCES}, got '{{d}}/a.xyz'"),
    "missing template": (lambda d, t: [str(d / "a.xyz"), "--template", str(t / "c.ply")],
                         "fit-batch --template: expected an existing control mesh file, got '{t}/c.ply'"),
    "missing scheduler file": (lambda d, t: [str(d / "a.xyz"), "--scheduler", str(t / "s.json")],
                               f"fit-batch --scheduler: expected {SCHEDULER}, got '{{t}}/s.json': no such file"),
    "scheduler file not JSON": (lambda d, t: [str(d / "a.xyz"), "--scheduler", str(_scheduler_file(t, "tcp://"))],
                                f"fit-batch --scheduler: expected {SCHEDULER}, got '{{t}}/sched.json': not a JSON "
                                "file (Expecting value: line 1 column 1 (char 0))"),
    "scheduler file without address": (
        lambda d, t: [str(d / "a.xyz"), "--scheduler", str(_scheduler_file(t, '{"type": "Scheduler"}'))],
        f"fit-batch --scheduler: expected {SCHEDULER}, got '{{t}}/sched.json' without an 'address' "
        "protocol://host:port"),
    "bad fit option": (lambda d, t: [str(d / "a.xyz"), "--alpha", "-1"],
                       "fit-batch --alpha: expected a finite number >= 0, got -1.0"),
    "bad sequence option": (lambda d, t: ["--sequences", str(d), "--iterations", "0"],
                            "fit-batch --iterations: expected an integer >= 1, got 0"),
    "poisson and a template": (
        lambda d, t: ["--sequences", str(d), "--poisson-template", "--template", "c.ply"],
        "fit-batch --poisson-template: expected no --template (it builds the template), got --template 'c.ply'"),
    "bad variant": (lambda d, t: [str(d / "a.xyz"), "--variant", "scalar_rgb"],
                    "fit-batch --variant: expected one of "),
}


def _copy(source, target):
    target.parent.mkdir(parents=True, exist_ok=True)
    shutil.copy(source, target)
    return target


@pytest.mark.parametrize("case", REJECTED, ids=list(REJECTED))
def test_a_bad_batch_is_refused_before_anything_runs(case, inputs, tmp_path, capsys):
    build, message = REJECTED[case]
    out = tmp_path / "out"
    line = one_line_error(capsys, ["fit-batch", *build(inputs, tmp_path), "-o", str(out)])
    expected = "mi-loop: error: " + message.format(d=inputs, t=tmp_path)
    assert line.startswith(expected) if case == "bad variant" else line == expected
    assert not out.exists()


@pytest.mark.parametrize("argv, message", [
    (["--scheduler", "tcp://h:1", "--workers", "2"], "mi-loop fit-batch: error: argument --workers: not allowed with "
                                                     "argument --scheduler"),
    (["--workers", "0"], "mi-loop fit-batch: error: argument --workers: expected a positive integer, got 0"),
    (["--views", "3"], "mi-loop: error: unrecognized arguments: --views 3"),             # a fit-sequence option
    (["--sequences", "--resume"], "mi-loop: error: unrecognized arguments: --resume"),   # not per batch
])
def test_usage_errors_exit_2(argv, message, inputs, tmp_path, capsys):
    with pytest.raises(SystemExit) as info:
        main(["fit-batch", str(inputs), "-o", str(tmp_path / "out"), *argv])
    assert info.value.code == 2
    assert capsys.readouterr().err == message + "\n"
    assert not (tmp_path / "out").exists()


def test_the_help_lists_fits_options_or_with_sequences_fit_sequences(capsys):
    texts = {}
    for extra in ([], ["--sequences"]):
        with pytest.raises(SystemExit):
            main(["fit-batch", *extra, "--help"])
        texts[bool(extra)] = " ".join(capsys.readouterr().out.split())
    assert "--tolerance" in texts[False] and "--views" not in texts[False]
    assert "--views VIEWS" in texts[True] and "--features" not in texts[True] and "--resume " not in texts[True]
    assert "--workers N worker processes of the local cluster, one thread each (default 2)" in texts[False]
    assert "Not taken with --sequences" in texts[True]


def test_quiet_and_debug_go_before_or_after_fit_batch_in_both_modes():
    parser = build_parser()
    for command in (["fit-batch", "a.ply", "-o", "x"], ["fit-batch", "--sequences", "s.npz", "-o", "x"]):
        for argv in ([*command, "-q"], ["-q", *command], [*command, "--quiet"], ["--quiet", *command]):
            args = parser.parse_args(argv)
            assert args.quiet is True and args.debug is False and args.sequences == ("--sequences" in command)
        assert parser.parse_args(command).quiet is False
    assert parser.parse_args(["fit-batch", "--seq", "s", "-o", "x", "--views", "3"]).views == 3   # abbreviated


def test_the_summary_reads_a_sequences_last_row_and_a_fits_report_as_written(tmp_path):
    """metrics.csv through mi_loop.io.runs: a frame name with a comma, empty drift cells, cells as written;
    and a summary.csv row of them reads back as the same cells."""
    from mi_loop.io.runs import MetricsRow, write_metrics

    seq = tmp_path / "seq"
    seq.mkdir()
    write_metrics(seq / "metrics.csv", [
        MetricsRow(0, "a", 0.1, 0.2, 0.3, 0.0, 0.01, 0.02, 1.0, 0.0, 30),
        MetricsRow(1, "scan 1, left", 1 / 3, 0.5, 1.25, 2.5, None, None, 1.5, 0.25, 20)])
    metrics = batch_summary.read_metrics(seq, True)
    assert metrics == {"frames": 2, "last_frame": "scan 1, left", "mean": "0.333333", "rms": "0.5",
                       "hausdorff": "1.25", "flipped_pct": "2.5", "drift_mean": "", "drift_p95": ""}
    path = batch_summary.write_summary(tmp_path / "summary.csv", ["seq"], {"seq": {"input": "s", "status": "done",
                                                                                  **metrics}}, True)
    with open(path, newline="") as f:
        row, = csv.DictReader(f)
    assert row["last_frame"] == "scan 1, left" and row["drift_mean"] == "" and row["frames"] == "2"
    fit = tmp_path / "fit"
    fit.mkdir()
    (fit / "report.json").write_text(json.dumps({"metrics": {"mean": 0.1, "rms": 0.2}, "params": {"iterations_run": 7},
                                                 "converged": True}))
    metrics = batch_summary.read_metrics(fit, False)
    assert (metrics["mean"], metrics["hausdorff"], metrics["iterations"], metrics["converged"]) == (0.1, "", 7, True)
    (fit / "report.json").write_text("[]")
    with pytest.raises(ValueError) as info:
        batch_summary.read_metrics(fit, False)
    assert str(info.value) == ("fit-batch summary: expected a report.json of mi-loop fit, a JSON object, got a list in "
                               f"'{fit / 'report.json'}'")
