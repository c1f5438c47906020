"""The files a ``fit-sequence`` run reads back, and a fit's ``report.json``: one writer and one reader each.

- ``metrics.csv``: one :class:`MetricsRow` per finished frame under :data:`CSV_HEADER`
  (:func:`write_metrics`, :func:`read_metrics`; through :mod:`csv`, so a frame name
  with a comma or a quote survives); a frame is finished once its row is there;
- ``sequence.json``: what the run needs to continue, written before the first frame
  (:class:`RunRecord`; :func:`write_run_json`, :func:`read_run_json`);
- ``state/NNNN.npz``: the exact state a finished frame leaves (:class:`FrameState`;
  :func:`write_state`, :func:`read_state`, :func:`state_path`): the float64 control
  points in the unit box, the faces, the template and free-form named arrays (the
  optimisers' state) that ``--resume`` continues from bit for bit (the PLY files in
  world units do not map back exactly);
- ``report.json`` of ``fit`` and ``fit-images``: :func:`read_report`.

Every writer is atomic (:func:`~mi_loop.io.files.atomic_open`); every rejected
file raises :class:`ValueError` with a one-line message naming the file.
"""
from __future__ import annotations

import csv
import json
from dataclasses import asdict, dataclass, field, fields
from io import StringIO
from pathlib import Path

import numpy as np

from mi_loop.errors import fail
from mi_loop.io.documents import read_json
from mi_loop.io.files import atomic_open, write_text

__all__ = ["COLUMNS", "CSV_HEADER", "OLDER_COLUMNS", "STATE_DIR", "FrameState", "MetricsRow", "RunRecord",
           "read_metrics", "read_report", "read_run_json", "read_state", "state_path", "write_metrics",
           "write_run_json", "write_state"]

#: The columns of ``metrics.csv``, in order.
COLUMNS = ("frame", "name", "mean", "rms", "hausdorff", "flipped_pct", "drift_mean", "drift_p95", "seconds",
           "time_render", "iterations")
#: Its header line.
CSV_HEADER = ",".join(COLUMNS)
#: The columns of runs from before the folds and the drift were measured (read by ``export`` and ``fit-batch``).
OLDER_COLUMNS = ("frame", "name", "mean", "rms", "hausdorff", "seconds", "time_render", "iterations")
#: Sub-directory of a run's OUTDIR with the exact state of every finished frame (``NNNN.npz``).
STATE_DIR = "state"

#: How each number is written (the text a row reads back from).
_FORMATS = {"mean": ".6g", "rms": ".6g", "hausdorff": ".6g", "flipped_pct": ".4g", "drift_mean": ".6g",
            "drift_p95": ".6g", "seconds": ".3f", "time_render": ".3f"}
_INTEGERS = ("frame", "iterations")
_OPTIONAL = ("flipped_pct", "drift_mean", "drift_p95")
_STATE_ARRAYS = ("x", "F", "rest")


@dataclass(frozen=True)
class MetricsRow:
    """One row of ``metrics.csv``: a finished frame's distances, folds, drift and costs.

    Distances are two-sided and relative to the bounding-box diagonal of the
    frame's target: the clean reference frame where there is one, else the
    frame's mesh or points.

    Attributes
    ----------
    frame : int
        The frame's index in the (selected) sequence.
    name : str
        The frame's name (any text: commas, quotes and line breaks are quoted in the file).
    mean, rms, hausdorff : float
        Mean, RMS and largest distance between the limit surface and the target.
    flipped_pct : float or None
        Share of the limit surface's area facing against the target (folds), in %;
        None in the rows of runs older than the column.
    drift_mean, drift_p95 : float or None
        Correspondence drift (mean, 95th percentile) relative to the diagonal:
        each control vertex's limit point attached at frame 0 to the clean frame 0
        and followed to the same barycentric point of frame ``t``; None (an empty
        cell) where the frames are not in correspondence.
    seconds : float
        Wall time of the frame, fit and metrics.
    time_render : float
        Seconds of it spent rendering.
    iterations : int
        Iterations the frame ran.
    """

    frame: int
    name: str
    mean: float
    rms: float
    hausdorff: float
    flipped_pct: float | None
    drift_mean: float | None
    drift_p95: float | None
    seconds: float
    time_render: float
    iterations: int

    def cells(self) -> dict:
        """Return the row as ``metrics.csv`` holds it: column -> text (``''`` for None).

        Returns
        -------
        dict
            :data:`COLUMNS` -> str.

        Examples
        --------
        >>> row = MetricsRow(0, "a, b", 1 / 3, 0.5, 1.0, 0.0, None, None, 2.5, 0.0, 30)
        >>> row.cells()["mean"], row.cells()["drift_mean"], row.cells()["seconds"]
        ('0.333333', '', '2.500')
        """
        out = {}
        for name in COLUMNS:
            value = getattr(self, name)
            out[name] = "" if value is None else format(value, _FORMATS[name]) if name in _FORMATS else str(value)
        return out

    def rounded(self) -> MetricsRow:
        """Return the row as :func:`read_metrics` reads it back: every number at the precision it is written with.

        Returns
        -------
        MetricsRow

        Examples
        --------
        >>> MetricsRow(0, "f", 1 / 3, 0.5, 1.0, 0.0, None, None, 2.5, 0.0, 30).rounded().mean
        0.333333
        """
        return _parse(self.cells(), "MetricsRow.rounded", "")


def _parse(cells: dict, where: str, place: str) -> MetricsRow:
    """A :class:`MetricsRow` from its cells (missing columns: None)."""
    values = {}
    for name in COLUMNS:
        text = cells.get(name)
        try:
            if name == "name":
                values[name] = text or ""
            elif text is None or (text == "" and name in _OPTIONAL):
                values[name] = None
            else:
                values[name] = int(text) if name in _INTEGERS else float(text)
        except ValueError:
            fail(where, f"{'an integer' if name in _INTEGERS else 'a number'} in column {name}", f"'{text}'{place}")
    return MetricsRow(**values)


def write_metrics(path, rows) -> Path:
    """Write ``metrics.csv`` atomically: :data:`CSV_HEADER`, then a line per row.

    Parameters
    ----------
    path : str or os.PathLike
        Destination; its directory must exist.
    rows : list of MetricsRow
        The finished frames, in order.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    text = StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(COLUMNS)
    writer.writerows([row.cells()[name] for name in COLUMNS] for row in rows)
    return write_text(path, text.getvalue())


def read_metrics(path, where: str = "read_metrics", *, older: bool = False) -> list:
    """Read ``metrics.csv``: the finished frames' rows.

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    where : str
        Who reads it, for messages (``"fit-sequence --resume"``).
    older : bool
        Also read the header of older runs (:data:`OLDER_COLUMNS`; their missing
        columns read as None). ``--resume`` does not: it continues only runs of
        this version.

    Returns
    -------
    list of MetricsRow
        In the file's order; empty for an empty file or a header alone.

    Raises
    ------
    ValueError
        A missing file; a header other than :data:`CSV_HEADER` (or, with ``older``,
        :data:`OLDER_COLUMNS`), named with what to do; a row of another length or a
        cell that is not a number, named with its line.

    Examples
    --------
    >>> import tempfile, os
    >>> with tempfile.TemporaryDirectory() as d:
    ...     path = os.path.join(d, "metrics.csv")
    ...     _ = write_metrics(path, [MetricsRow(0, "scan, left", 0.01, 0.02, 0.1, 0.5, None, None, 1.0, 0.0, 20)])
    ...     [(r.name, r.drift_mean) for r in read_metrics(path)]
    [('scan, left', None)]
    """
    path = Path(path)
    if not path.is_file():
        fail(where, "a metrics.csv file", f"no '{path}'")
    with open(path, newline="", encoding="utf-8") as f:
        lines = list(csv.reader(f))
    if not lines:
        return []
    header = tuple(lines[0])
    if header != COLUMNS and not (older and header == OLDER_COLUMNS):
        fix = ("a run of an older version: start it again without --resume" if not older
               else "not a metrics.csv of mi-loop fit-sequence")
        fail(where, f"a metrics.csv with the columns {CSV_HEADER}", f"'{','.join(header)}' in '{path}' ({fix})")
    rows = []
    for line, cells in enumerate(lines[1:], start=2):
        if not cells:
            continue
        if len(cells) != len(header):
            fail(where, f"{len(header)} cells in every row of '{path}'", f"{len(cells)} in line {line}")
        rows.append(_parse(dict(zip(header, cells)), where, f" in line {line} of '{path}'"))
    return rows


@dataclass
class RunRecord:
    """``sequence.json``: what a ``fit-sequence`` run needs to continue, and what it ran with.

    Every attribute is one key of the file; older runs' files may lack some (they read as None).

    Attributes
    ----------
    centre : list of 3 float
        With ``scale``, the normalisation: unit-box coordinates are ``(world - centre) / scale``.
    scale : float
        See ``centre``.
    lr : float
        Base step size in the unit box (2 % of the template's mean edge length).
    camera_box : list ``[lo, hi]``
        The unit-box box the camera rig frames, fixed for the whole run.
    options : dict
        Every field of :class:`~mi_loop.fitting.options.SequenceOptions`, as the run used
        them (``--resume`` keeps these and says which given options differ).
    n_frames : int
        Frames in the sequence at the start.
    template : dict
        Its ``source`` (``file``, ``mesh``, ``poisson`` or ``poisson+hull``), ``n_vertices``,
        ``n_faces``; for ``--template`` also ``path``, ``split_polygons`` (polygons
        triangulated on reading), ``size_ratio`` and ``centre_offset`` (against the first frame).
    normals_estimated : bool
        Whether the first frame's normals were estimated (point clouds without normals).
    images : list of str or None
        The captures (``transforms.json`` per frame).
    emitters : str or None
        The photos' lighting file (None: a constant environment).
    reference : bool
        Whether distances, folds and drift are measured against clean meshes in correspondence.
    variant : str
        The Mitsuba variant of the run.
    fps : float or None
        The frame rate of ``sequence.glb`` (``--fps``; ``--resume`` keeps it).
    """

    centre: list | None = None
    scale: float | None = None
    lr: float | None = None
    camera_box: list | None = None
    options: dict | None = None
    n_frames: int | None = None
    template: dict | None = None
    normals_estimated: bool | None = None
    images: list | None = None
    emitters: str | None = None
    reference: bool | None = None
    variant: str | None = None
    fps: float | None = None


def write_run_json(path, record: RunRecord) -> Path:
    """Write ``sequence.json`` atomically (indented JSON, the keys in :class:`RunRecord`'s order).

    Parameters
    ----------
    path : str or os.PathLike
        Destination; its directory must exist.
    record : RunRecord
        Plain JSON values only (lists, not arrays).

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    return write_text(path, json.dumps(asdict(record), indent=2) + "\n")


def read_run_json(path, where: str = "read_run_json") -> RunRecord:
    """Read ``sequence.json``.

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    where : str
        Who reads it, for messages (``"fit-sequence --resume"``).

    Returns
    -------
    RunRecord
        Keys the file lacks (older runs) read as None; keys this version does not know are ignored.

    Raises
    ------
    ValueError
        ``where: expected the run's sequence.json next to its metrics.csv, got no 'path'``;
        a file that is not a JSON object.
    """
    want = "the run's sequence.json next to its metrics.csv"
    if not Path(path).is_file():
        fail(where, want, f"no '{path}'")
    document = read_json(path, where, want)
    if not isinstance(document, dict):
        fail(where, f"{want}, a JSON object", f"a {type(document).__name__} in '{path}'")
    return RunRecord(**{f.name: document[f.name] for f in fields(RunRecord) if f.name in document})


@dataclass(eq=False)
class FrameState:
    """``state/NNNN.npz``: the exact state a finished frame leaves for the next one.

    Attributes
    ----------
    x : (n, 3) float64 NumPy array
        The frame's control points in the unit box.
    F : (m, 3) int64 NumPy array
        The control faces.
    rest : (n, 3) float64 NumPy array or None
        The template, the second ARAP rest shape (None in the files of runs older than it).
    extra : dict
        Name -> NumPy array: whatever else the fit keeps (the albedo and its optimiser's
        state); stored and read back as they are, without being interpreted.
    """

    x: np.ndarray
    F: np.ndarray
    rest: np.ndarray | None = None
    extra: dict = field(default_factory=dict)


def state_path(out, t: int) -> Path:
    """Return the path of frame ``t``'s state file in a run's OUTDIR: ``OUT/state/NNNN.npz``.

    Parameters
    ----------
    out : str or os.PathLike
        The run's OUTDIR.
    t : int
        The frame.

    Returns
    -------
    pathlib.Path

    Examples
    --------
    >>> state_path("out", 7).as_posix()
    'out/state/0007.npz'
    """
    return Path(out) / STATE_DIR / f"{t:04d}.npz"


def write_state(path, state: FrameState) -> Path:
    """Write a state file atomically (``x`` as float64, ``F`` as int64, ``rest`` as float64, then ``extra``).

    Parameters
    ----------
    path : str or os.PathLike
        Destination (:func:`state_path`); its directory must exist.
    state : FrameState
        ``extra`` may not use the names ``x``, ``F`` or ``rest``.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    ValueError
        An ``extra`` array named like one of the fixed ones.
    """
    taken = sorted(set(state.extra) & set(_STATE_ARRAYS))
    if taken:
        fail("write_state", f"extra arrays named other than {', '.join(_STATE_ARRAYS)}", f"{taken}")
    arrays = {"x": np.asarray(state.x, dtype=np.float64), "F": np.asarray(state.F, dtype=np.int64)}
    if state.rest is not None:
        arrays["rest"] = np.asarray(state.rest, dtype=np.float64)
    arrays.update({name: np.asarray(a) for name, a in state.extra.items()})
    with atomic_open(path) as f:
        np.savez(f, **arrays)
    return Path(path)


def read_state(path, where: str = "read_state") -> FrameState:
    """Read a state file.

    Parameters
    ----------
    path : str or os.PathLike
        The file (:func:`state_path`).
    where : str
        Who reads it, for messages.

    Returns
    -------
    FrameState
        Every array besides ``x``, ``F`` and ``rest`` in ``extra``, in the file's order.

    Raises
    ------
    ValueError
        A file that is not an NPZ file or lacks ``x`` or ``F``.
    """
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {name: np.array(z[name]) for name in z.files}
    except (OSError, EOFError, ValueError) as exc:
        fail(where, "a state file (NPZ) of fit-sequence", f"'{path}': {type(exc).__name__}: {exc}")
    missing = [name for name in ("x", "F") if name not in arrays]
    if missing:
        fail(where, "a state file with the arrays x and F", f"'{path}' without {', '.join(missing)}")
    return FrameState(arrays.pop("x"), arrays.pop("F"), arrays.pop("rest", None), arrays)


def read_report(path, where: str = "read_report") -> dict:
    """Read the ``report.json`` of a ``fit`` or ``fit-images`` result.

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    where : str
        Who reads it, for messages.

    Returns
    -------
    dict
        The report as written (``metrics``, ``params``, ``converged``, ...).

    Raises
    ------
    ValueError
        A missing file or one that is not a JSON object.
    """
    report = read_json(path, where, "a report.json of mi-loop fit")
    if not isinstance(report, dict):
        fail(where, "a report.json of mi-loop fit, a JSON object", f"a {type(report).__name__} in '{path}'")
    return report
