"""What ``fit-sequence`` fits its frames with besides themselves: photos, lighting, a clean reference.

- :class:`Sources` and :func:`read_sources`: the captures (one ``transforms.json``
  per frame) and the clean reference frames, their counts checked against the
  frames and cut by ``--frames`` alike;
- :func:`read_views`: one frame's photos, checked against the frame's points
  (masks present, cameras that see the points).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mi_loop import io
from mi_loop.errors import expected, fail

__all__ = ["Sources", "captures_phrase", "read_sources", "read_views"]


@dataclass(frozen=True)
class Sources:
    """What the frames are fitted with besides themselves: photos, lighting and a clean reference.

    Attributes
    ----------
    captures : list of pathlib.Path or None
        One ``transforms.json`` per (selected) frame.
    emitters : pathlib.Path or None
        Mitsuba XML of the capture's lighting (None: constant environment, radiance 1).
    reference : list of mi_loop.io.frames.Frame or None
        Clean meshes or points in correspondence, one per (selected) frame, for
        the distances, folds and drift (the frames themselves when they are such meshes or points).
    """

    captures: list | None = None
    emitters: Path | None = None
    reference: list | None = None


def read_sources(frames: list, images, emitters, reference, selection: slice | None, log) -> Sources:
    """List the captures and read the reference of a sequence, counts checked, all cut by ``selection``.

    Parameters
    ----------
    frames : list of mi_loop.io.frames.Frame
        Every frame of the sequence (before ``selection``).
    images : list of str or os.PathLike or None
        ``--images``: captures (files, directories, globs; :func:`mi_loop.io.capture.list_captures`).
    emitters : pathlib.Path or None
        ``--emitters``.
    reference : pathlib.Path or None
        ``--reference``: clean meshes or points in correspondence (an NPZ), one per frame.
    selection : slice or None
        ``--frames``.
    log : mi_loop.app.progress.Reporter
        Told when the frames themselves are the reference.

    Returns
    -------
    Sources

    Raises
    ------
    ValueError
        Another number of captures or reference frames than of frames, a reference not in correspondence.
    """
    from mi_loop.io.capture import list_captures
    from mi_loop.io.frames import select_frames

    n = len(frames)
    captures = None
    if images:
        captures = list_captures(images, where="fit-sequence --images")
        if len(captures) != n:
            fail("fit-sequence --images", f"one transforms.json per frame ({n} frames)", f"{len(captures)} captures")
        captures = select_frames(captures, selection, "fit-sequence --frames")
    ref = None
    if reference is not None:
        ref = io.read_frames([reference])
        if len(ref) != n:
            fail("fit-sequence --reference", f"one reference frame per frame ({n} frames)",
                 f"{len(ref)} in '{reference}'")
        if not all(f.correspondence for f in ref):
            fail("fit-sequence --reference", "meshes or points in correspondence (an NPZ with vertices (T, V, 3) "
                 "and faces, or with points (T, N, 3))", f"'{reference}'")
        ref = select_frames(ref, selection, "fit-sequence --frames")
    elif all(getattr(f, "correspondence", False) for f in frames):
        ref = select_frames(frames, selection, "fit-sequence --frames")
        log.say("frames in correspondence: the correspondence drift is measured against them")
    return Sources(captures, emitters, ref)


def captures_phrase(k: int) -> str:
    """How messages count captures (``--images``).

    Parameters
    ----------
    k : int
        The number of captures.

    Returns
    -------
    str

    Examples
    --------
    >>> captures_phrase(1), captures_phrase(3)
    ('1 capture', '3 captures')
    """
    return f"{k} capture{'' if k == 1 else 's'}"


def read_views(path: Path, t: int, frame) -> list:
    """Read frame ``t``'s photos (:func:`~mi_loop.io.capture.read_capture`), checked against the frame's points.

    Parameters
    ----------
    path : pathlib.Path
        The frame's ``transforms.json``.
    t : int
        The frame, for messages.
    frame : mi_loop.app.inputs.FitFrame
        The frame; its points must lie inside the photos' masks.

    Returns
    -------
    list of mi_loop.io.views.View

    Raises
    ------
    ValueError
        Fewer than two photos, a capture without masks (every view all foreground), or
        cameras that do not see the frame's points (another frame's capture, other units).
    """
    from mi_loop.fitting.hull import in_mask
    from mi_loop.io.capture import read_capture

    views = list(read_capture(path).views)
    if len(views) < 2:
        raise ValueError(expected("fit-sequence --images", f"at least two photos in '{path}' (frame {t})",
                                  f"{len(views)}"))
    if all((v.mask if v.valid is None else v.mask[v.valid > 0]).min() >= 1.0 for v in views):   # seen pixels
        raise ValueError(expected("fit-sequence --images", f"masks in the capture of frame {t} (an alpha "
                                  "channel or mask_path: the silhouettes come from them)",
                                  f"none in '{path}' (every pixel of every photo is foreground)"))
    P = frame.P[np.random.default_rng(0).choice(len(frame.P), min(len(frame.P), 2000), replace=False)]
    share = float(np.median([np.sum(in_mask(v, P)[1]) / len(P) for v in views]))
    if share < 0.5:
        raise ValueError(expected(
            "fit-sequence --images", f"cameras of '{path}' that see frame {t}'s points inside the masks",
            f"{100 * share:.0f} % of them in the median photo (a capture of another frame, or other "
            "units or coordinates than the frames?)"))
    return views
