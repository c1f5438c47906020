"""``OUTDIR/summary.csv`` of ``mi-loop fit-batch``, and what a finished output directory holds.

``summary.csv`` has a row per finished input, in the order of the inputs:
:data:`COLUMNS`, then the metrics of the fit: :data:`FIT_METRICS` from its
``report.json`` (two-sided distances relative to the data's bounding-box
diagonal, iterations, convergence) or :data:`SEQUENCE_METRICS` (the frames
fitted and the last frame's row of ``metrics.csv``). Fields are quoted as the
:mod:`csv` module does (errors hold commas). ``OUTDIR/report.html``
(:func:`write_index`) shows the same table in a browser, each finished input
linked to its own ``report.html``.
"""
from __future__ import annotations

import csv
from io import StringIO
from pathlib import Path

from mi_loop import io
from mi_loop.app.results import FIT_OUTPUTS, SEQUENCE_OUTPUTS
from mi_loop.io import runs

__all__ = ["COLUMNS", "FIT_METRICS", "INDEX", "SEQUENCE_METRICS", "SEQUENCE_OUTPUTS", "SUMMARY", "complete",
           "read_metrics", "write_index", "write_summary"]

#: The first columns of ``summary.csv``; ``status`` is ``done``, ``failed`` or ``skipped``.
COLUMNS = ("input", "status", "seconds", "worker", "error")
#: Then, for fits: ``report.json``'s metrics, iterations and convergence.
FIT_METRICS = ("mean", "rms", "hausdorff", "p2s_mean", "p2s_max", "s2p_mean", "s2p_max", "flipped_area_pct",
               "self_intersecting_pct", "iterations", "converged")
#: Or, for sequences: frames fitted and the last frame's row of ``metrics.csv``.
SEQUENCE_METRICS = ("frames", "last_frame", "mean", "rms", "hausdorff", "flipped_pct", "drift_mean", "drift_p95")
#: The summary's file name in OUTDIR.
SUMMARY = "summary.csv"
#: The index page's file name in OUTDIR (and of each input's report in ``OUTDIR/<name>/``).
INDEX = "report.html"


def complete(output: Path, sequence: bool) -> bool:
    """Return whether ``output`` holds every output of a finished fit (or fit-sequence).

    Parameters
    ----------
    output : pathlib.Path
        ``OUTDIR/<name>``.
    sequence : bool
        Outputs of ``fit-sequence`` (:data:`SEQUENCE_OUTPUTS` and ``control/``) instead of
        ``fit``'s (:data:`~mi_loop.app.results.FIT_OUTPUTS`).

    Returns
    -------
    bool
    """
    if sequence:
        return all((output / name).is_file() for name in SEQUENCE_OUTPUTS) and (output / "control").is_dir()
    return all((output / name).is_file() for name in FIT_OUTPUTS)


def read_metrics(output: Path, sequence: bool) -> dict:
    """Read the summary's metrics of a finished fit (``report.json``) or sequence (``metrics.csv``).

    Parameters
    ----------
    output : pathlib.Path
        ``OUTDIR/<name>``, complete (:func:`complete`).
    sequence : bool
        A ``fit-sequence`` output.

    Returns
    -------
    dict
        :data:`FIT_METRICS` or :data:`SEQUENCE_METRICS` -> value (``''`` where the file has none); a
        sequence's values are the cells of ``metrics.csv``'s last row as written.

    Raises
    ------
    ValueError
        A ``metrics.csv`` or ``report.json`` that does not read (:mod:`mi_loop.io.runs`).
    """
    if sequence:
        rows = runs.read_metrics(output / "metrics.csv", "fit-batch summary", older=True)
        last = rows[-1].cells() if rows else {}
        return {"frames": len(rows), "last_frame": last.get("name", ""),
                **{k: last.get(k, "") for k in SEQUENCE_METRICS[2:]}}
    report = runs.read_report(output / "report.json", "fit-batch summary")
    return {**{k: report["metrics"].get(k, "") for k in FIT_METRICS[:-2]},
            "iterations": report["params"].get("iterations_run", ""), "converged": report.get("converged", "")}


def write_summary(path: Path, names: list, rows: dict, sequence: bool) -> Path:
    """Write ``summary.csv`` atomically: a row per finished task, in the tasks' order.

    Parameters
    ----------
    path : pathlib.Path
        ``OUTDIR/summary.csv``.
    names : list of str
        The output names of every input of the batch, in order.
    rows : dict
        Output name -> row (:data:`COLUMNS` and metrics) of the finished ones.
    sequence : bool
        The metrics columns: :data:`SEQUENCE_METRICS`, else :data:`FIT_METRICS`.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    columns = COLUMNS + (SEQUENCE_METRICS if sequence else FIT_METRICS)
    text = StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(columns)
    writer.writerows([rows[name].get(c, "") for c in columns] for name in names if name in rows)
    return io.write_text(path, text.getvalue())


def write_index(path: Path, names: list, rows: dict, sequence: bool) -> Path:
    """Write the batch's ``report.html`` atomically: the summary's table, each input's ``report.html`` linked.

    Parameters
    ----------
    path : pathlib.Path
        ``OUTDIR/report.html``.
    names : list of str
        The output names of every input of the batch, in order.
    rows : dict
        Output name -> row (:data:`COLUMNS` and metrics) of the finished ones.
    sequence : bool
        The metrics columns: :data:`SEQUENCE_METRICS`, else :data:`FIT_METRICS`.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    from mi_loop.app.html_report import index_page

    columns = COLUMNS + (SEQUENCE_METRICS if sequence else FIT_METRICS)
    done = [name for name in names if name in rows]
    links = [f"{name}/{INDEX}" if (path.parent / name / INDEX).is_file() else None for name in done]
    title = f"mi-loop fit-batch{' --sequences' if sequence else ''}: {path.parent.name}"
    return io.write_text(path, index_page(title, columns, [rows[name] for name in done], links))
