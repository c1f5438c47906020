"""Where the jobs report: progress lines and bars on stderr, warnings, written paths on stdout.

``--quiet`` silences the progress (the ``[mi-loop  12.3s] ...`` lines and the
bars) but never the warnings, the errors or the written paths.
"""
from __future__ import annotations

import contextlib
import sys
import time

__all__ = ["Reporter"]


class Reporter:
    """Progress, warnings and written paths of one ``mi-loop`` command.

    Parameters
    ----------
    quiet : bool
        No progress lines and no progress bars.
    start : float, optional
        ``time.perf_counter()`` at the start of the command (default: now);
        progress lines show the seconds since.

    Examples
    --------
    >>> log = Reporter(quiet=True)
    >>> log.say("not shown")
    >>> log.wrote("out/control.ply")
    out/control.ply
    """

    def __init__(self, quiet: bool = False, start: float | None = None):
        self.quiet = quiet
        self.start = time.perf_counter() if start is None else start
        self._bar = None

    def _err(self, line: str) -> None:
        if self._bar is not None:            # above the bar, which stays at the bottom
            self._bar.write(line, file=sys.stderr)
        else:
            print(line, file=sys.stderr, flush=True)

    def say(self, message: str) -> None:
        """A progress line ``[mi-loop  12.3s] message`` on stderr (not with ``quiet``)."""
        if not self.quiet:
            self._err(f"[mi-loop {time.perf_counter() - self.start:6.1f}s] {message}")

    def warning(self, message: str) -> None:
        """A warning ``mi-loop: warning: message`` on stderr (also with ``quiet``)."""
        self._err(f"mi-loop: warning: {message}")

    def wrote(self, *paths) -> None:
        """Print written paths on stdout, one a line (also with ``quiet``)."""
        for path in paths:
            print(path, flush=True)

    @contextlib.contextmanager
    def bar(self, desc: str, unit: str = "it"):
        """A progress bar on stderr; yields ``update(done, total, postfix='')``.

        The bar appears at the first update (so an early error prints one line
        only) and disappears when the block ends. It is drawn only when stderr
        is a terminal (a log file gets the progress lines, not carriage
        returns); with ``quiet`` updates do nothing.
        """
        if self.quiet:
            yield lambda done, total, postfix="": None
            return
        from tqdm import tqdm

        def update(done, total, postfix=""):
            if self._bar is None:
                self._bar = tqdm(total=total, desc=desc, unit=unit, leave=False, dynamic_ncols=True,
                                 file=sys.stderr, disable=None)
            if self._bar.total != total:
                self._bar.total = total
            if postfix:
                self._bar.set_postfix_str(postfix, refresh=False)
            self._bar.update(done - self._bar.n)

        try:
            yield update
        finally:
            if self._bar is not None:
                self._bar.close()
                self._bar = None
