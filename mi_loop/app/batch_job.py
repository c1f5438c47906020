"""The ``mi-loop fit-batch`` job: many fits on a Dask cluster, one atomic output directory each, one summary.

Every input is one task (:func:`fit_task`), run on a worker of the cluster
(:mod:`mi_loop.app.cluster`) exactly as ``mi-loop fit INPUT -o OUTDIR/<name>/``
(or ``fit-sequence``) would run it: the same options, seed and code, so the
same files whichever worker runs it. ``<name>`` is the input's file name
without its suffix (a directory's name); two inputs of one name are refused
before anything runs.

- ``OUTDIR/<name>/`` is written in a hidden sibling directory and renamed
  when the fit is done (:func:`~mi_loop.io.files.staged_directory`): a failed
  or interrupted input leaves none. A complete one (every output of ``fit``,
  or of a finished ``fit-sequence``) is skipped when the batch runs again; a
  failed one is fitted again.
- ``OUTDIR/summary.csv`` (:mod:`~mi_loop.app.batch_summary`) has a row per
  finished input, rewritten atomically as each one finishes: an interrupted
  batch keeps the rows of the inputs it finished. ``OUTDIR/report.html`` is
  the same table as a page, rewritten with it, that links each finished
  input's ``OUTDIR/<name>/report.html``.
- A failed input does not stop the others; when all have finished,
  :class:`BatchError` names how many failed.
"""
from __future__ import annotations

import glob
import os
import threading
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

from distributed import WorkerPlugin

from mi_loop import io
from mi_loop.app.batch_summary import INDEX, SUMMARY, complete, read_metrics, write_index, write_summary
from mi_loop.app.progress import Reporter
from mi_loop.errors import FitError, fail
from mi_loop.render.variant import DEFAULT_VARIANT

__all__ = ["BatchError", "Task", "WorkerSetup", "fit_task", "list_inputs", "output_names", "run"]

_WHERE = "fit-batch INPUTS"
_ONE_FIT = threading.Lock()     # one fit at a time per process: Dr.Jit's state and thread pool are the process's


class BatchError(RuntimeError):
    """Some inputs of a batch failed (each one's error is in ``summary.csv``); the others are done."""


@dataclass(frozen=True)
class Task:
    """One input of a batch, as a worker receives it.

    Attributes
    ----------
    input : pathlib.Path
        The input, absolute (a worker's working directory may be another).
    output : pathlib.Path
        Its absolute output directory ``OUTDIR/<name>``.
    options : FitOptions or SequenceOptions
        The fit's options; a :class:`~mi_loop.fitting.options.SequenceOptions` makes it a sequence.
    settings : dict
        The job's other keywords: ``template`` (absolute), ``variant``, ``view_level`` (and ``frames``
        for sequences).
    label : str
        The input as given, for ``summary.csv`` (default: ``input``).
    """

    input: Path
    output: Path
    options: object
    settings: dict = field(default_factory=dict)
    label: str = ""

    @property
    def shown(self) -> str:
        """The input as ``summary.csv`` shows it: ``label``, else ``input``."""
        return self.label or str(self.input)

    @property
    def sequence(self) -> bool:
        from mi_loop.fitting.options import SequenceOptions

        return isinstance(self.options, SequenceOptions)


class WorkerSetup(WorkerPlugin):
    """Prepare each Dask worker, in its main thread, before it runs a task: pymeshlab, then the variant.

    pymeshlab loaded for the first time in another thread than the main one,
    once Dr.Jit is loaded, corrupts the heap (glibc aborts the process at exit:
    ``malloc_consolidate(): unaligned fastbin chunk detected``), and a worker
    runs its tasks in other threads; so it is imported here, in the worker's
    main thread (where the plugin's ``setup`` runs), with the Mitsuba variant.

    Parameters
    ----------
    variant : str
        The Mitsuba variant of the batch's fits.
    threads : int, optional
        Dr.Jit threads per worker (a local cluster shares the machine's cores
        between its workers); None keeps Dr.Jit's default, every core.
    """

    name = "mi-loop-worker-setup"

    def __init__(self, variant: str = DEFAULT_VARIANT, threads: int | None = None):
        self.variant, self.threads = variant, threads

    def setup(self, worker) -> None:
        import pymeshlab  # noqa: F401

        from mi_loop.render.variant import set_variant

        set_variant(self.variant)
        if self.threads is not None:
            import drjit as dr

            dr.set_thread_count(self.threads)


class _TaskLog(Reporter):
    """A worker's reporter: no progress and no printed paths; warnings kept for the batch to print."""

    def __init__(self):
        super().__init__(quiet=True)
        self.warnings = []

    def warning(self, message: str) -> None:
        self.warnings.append(message)

    def wrote(self, *paths) -> None:
        pass


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def _worker() -> str:
    """The address of the Dask worker running the task (``local`` outside one)."""
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):
        return "local"


def fit_task(task: Task) -> dict:
    """Fit one input into its output directory, atomically; a failed fit is a row, not an exception.

    Parameters
    ----------
    task : Task

    Returns
    -------
    dict
        The summary row (:data:`COLUMNS` and the metrics) and ``warnings``, the job's warnings.
    """
    from mi_loop.app import fit_job, sequence_job
    from mi_loop.io.files import staged_directory

    log = _TaskLog()
    row = {"input": task.shown, "worker": _worker(), "error": ""}
    with _ONE_FIT:
        start = time.perf_counter()
        try:
            with staged_directory(task.output) as stage:
                if task.sequence:
                    sequence_job.run([task.input], stage, task.options, log=log, **task.settings)
                else:
                    fit_job.run(task.input, stage, task.options, log=log, **task.settings)
            row.update(status="done", **read_metrics(task.output, task.sequence))
        except (FitError, ValueError, TypeError, OSError, RuntimeError, ImportError) as exc:   # as cli.main reports
            row.update(status="failed", error=_one_line(exc))
        row.update(seconds=round(time.perf_counter() - start, 2), warnings=log.warnings)
    return row


def _usable(path: Path, sequences: bool) -> bool:
    from mi_loop.io.points import POINT_SUFFIXES

    if sequences:
        return path.is_dir() or (path.is_file() and path.suffix.lower() == ".npz")
    return path.is_file() and path.suffix.lower() in POINT_SUFFIXES


def list_inputs(items, sequences: bool) -> list:
    """List a batch's inputs: files (sequences: directories or NPZ files), quoted glob patterns expanded.

    Parameters
    ----------
    items : list of str or os.PathLike
        INPUTS as given.
    sequences : bool
        ``--sequences``.

    Returns
    -------
    list of pathlib.Path
        In the order given, each pattern's matches sorted.

    Raises
    ------
    ValueError
        A missing path, a pattern that matches nothing usable, an input of the wrong kind.
    """
    from mi_loop.io.points import POINT_SUFFIXES

    want = ("sequences: directories of frames or NPZ files (vertices (T, V, 3), faces)" if sequences else
            f"point-cloud or mesh files ({' '.join(POINT_SUFFIXES)}; directories only with --sequences)")
    found = []
    for item in items:
        p = Path(item)
        if p.exists():
            if not _usable(p, sequences):
                fail(_WHERE, want, f"'{p}'")
            found.append(p)
        elif any(c in str(item) for c in "*?["):       # a quoted glob pattern
            matches = [m for m in sorted(Path(m) for m in glob.glob(str(item))) if _usable(m, sequences)]
            if not matches:
                fail(_WHERE, f"{want} matching the pattern", f"none for '{item}'")
            found += matches
        else:
            fail(_WHERE, "existing files or directories, or quoted glob patterns", f"'{p}': no such file or directory")
    return found


def output_names(inputs) -> list:
    """Return the output directory name of each input: a file's stem, a directory's name.

    Parameters
    ----------
    inputs : list of pathlib.Path
        :func:`list_inputs`' result.

    Returns
    -------
    list of str

    Raises
    ------
    ValueError
        If two inputs have one name; the message names both.

    Examples
    --------
    >>> output_names([Path("scans/bunny.ply"), Path("scans/dragon.xyz")])
    ['bunny', 'dragon']
    """
    seen = {}
    for p in inputs:
        name = p.absolute().name if p.is_dir() else p.stem
        if name in seen:
            fail(_WHERE, "inputs of distinct names (each is fitted into OUTDIR/<name>/)",
                 f"'{seen[name]}' and '{p}', both named '{name}'")
        seen[name] = p
    return list(seen)


def _finished(task: Task):
    """The ``skipped`` row of a task whose output directory is complete, else None (it is fitted)."""
    if not complete(task.output, task.sequence):
        return None
    try:
        metrics = read_metrics(task.output, task.sequence)
    except (OSError, ValueError, KeyError, IndexError):      # complete but unreadable: fit it again
        return None
    return {"input": task.shown, "status": "skipped", **metrics}


def _collect(client, todo: list, names: list, rows: dict, summary: Path, shown: Path, log) -> None:
    """Submit ``todo``; as each task finishes, record its row, rewrite the summary, report progress."""
    from distributed import as_completed

    tasks, futures = {}, []
    for task in todo:
        key = f"fit-batch-{task.output.name}-{uuid.uuid4().hex[:8]}"
        tasks[key] = task
        futures.append(client.submit(fit_task, task, key=key, pure=False))
    failed = 0
    with log.bar("fit-batch", unit="input") as update:
        update(0, len(todo))
        for n, future in enumerate(as_completed(futures), start=1):
            task = tasks[future.key]
            name = task.output.name
            try:
                row = future.result()
            except Exception as exc:     # fit_task returns its failures: this is a dead worker or a lost cluster
                row = {"input": task.shown, "status": "failed", "error": f"{type(exc).__name__}: {_one_line(exc)}"}
            for message in row.pop("warnings", []):
                log.warning(f"{name}: {message}")
            rows[name] = row
            write_summary(summary, names, rows, task.sequence)
            write_index(summary.parent / INDEX, names, rows, task.sequence)
            failed += row["status"] == "failed"
            where = f" after {row['seconds']:.1f} s on {row['worker']}" if "seconds" in row else ""
            log.say(f"{name}: {row['status']}{where}" + (f": {row['error']}" if row["error"] else ""))
            if row["status"] == "done":
                log.wrote(shown / name)
            update(n, len(todo), f"{failed} failed" if failed else "")


def run(inputs, output, options, *, scheduler: str | None = None, workers: int | None = None,
        template: Path | None = None, variant: str = DEFAULT_VARIANT, frames: slice | None = None, log,
        view_level: int | None = None) -> Path:
    """Run ``mi-loop fit-batch``: fit every input on a Dask cluster; return the path of ``summary.csv``.

    Parameters
    ----------
    inputs : list of str or os.PathLike
        Files (sequences: directories or NPZ files) or quoted glob patterns (:func:`list_inputs`).
    output : pathlib.Path
        OUTDIR (created): ``OUTDIR/<name>/`` per input and ``OUTDIR/summary.csv``.
    options : FitOptions or SequenceOptions
        The options of every fit; :class:`~mi_loop.fitting.options.SequenceOptions` fits sequences.
    scheduler : str, optional
        A running cluster's scheduler address or file (:func:`~mi_loop.app.cluster.scheduler_address`);
        default a local cluster.
    workers : int, optional
        Worker processes of the local cluster (default :data:`~mi_loop.app.cluster.LOCAL_WORKERS`).
    template : pathlib.Path, optional
        Control mesh every fit starts from.
    variant : str
        Mitsuba variant of the workers.
    frames : slice, optional
        The frames of every sequence to fit (``--frames``; sequences only).
    log : mi_loop.app.progress.Reporter
    view_level : int, optional
        Tessellation level of every ``limit.glb`` / ``sequence.glb`` (``--view-level``); default the jobs'.

    Returns
    -------
    pathlib.Path
        ``OUTDIR/summary.csv``, printed (then ``OUTDIR/report.html``) after the output directory of every
        input done.

    Raises
    ------
    ValueError
        Before anything runs: an input missing or of the wrong kind, two inputs of one name, a missing
        template, a bad scheduler address or file, no scheduler answering there.
    BatchError
        When every input has finished and some failed.
    """
    from mi_loop.app.cluster import LOCAL_WORKERS, connect, scheduler_address
    from mi_loop.fitting.options import SequenceOptions
    from mi_loop.io.files import remove_stale_stages

    sequence = isinstance(options, SequenceOptions)
    paths = list_inputs(inputs, sequence)
    names = output_names(paths)
    if template is not None and not Path(template).is_file():
        fail("fit-batch --template", "an existing control mesh file", f"'{template}'")
    if scheduler is not None:
        scheduler_address(scheduler)
    settings = {"template": None if template is None else Path(template).absolute(), "variant": variant}
    if view_level is not None:
        settings["view_level"] = view_level
    if sequence:
        settings["frames"] = frames
    created = io.first_missing_ancestor(output)
    out = io.ensure_writable_dir(output).absolute()
    summary = out / SUMMARY
    tasks = [Task(p.absolute(), out / name, options, settings, str(p)) for p, name in zip(paths, names)]
    rows = {t.output.name: row for t in tasks if (row := _finished(t)) is not None}
    todo = [t for t in tasks if t.output.name not in rows]
    log.say(f"{len(tasks)} input{'s' * (len(tasks) != 1)}: {len(todo)} to fit"
            + (f", {len(rows)} complete already (skipped)" if rows else ""))
    try:
        if todo:
            for task in todo:
                remove_stale_stages(task.output)
            with connect(scheduler, workers, log) as client:
                # A local cluster's workers share this machine: its cores split between them.
                threads = max(1, (os.cpu_count() or 1) // (workers or LOCAL_WORKERS)) if scheduler is None else None
                client.register_plugin(WorkerSetup(variant, threads))
                write_summary(summary, names, rows, sequence)
                write_index(out / INDEX, names, rows, sequence)
                _collect(client, todo, names, rows, summary, Path(output), log)
        else:
            write_summary(summary, names, rows, sequence)
            write_index(out / INDEX, names, rows, sequence)
    except BaseException:
        if not summary.exists():
            io.remove_if_empty(created, out)
        raise
    log.wrote(Path(output) / SUMMARY, Path(output) / INDEX)
    failed = [t.output.name for t in tasks if rows.get(t.output.name, {}).get("status") == "failed"]
    if failed:
        names = ", ".join(failed[:3]) + (", ..." if len(failed) > 3 else "")
        raise BatchError(f"fit-batch: {len(failed)} of {len(tasks)} inputs failed ({names}); "
                         f"their errors are in {Path(output) / SUMMARY}")
    return summary
