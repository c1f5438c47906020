"""Output files written atomically, and output directories that a failed run leaves as they were.

Every write goes to a temporary file in the destination's directory, which
then replaces the destination with :func:`os.replace`, so a crash never leaves
a half-written file behind; :func:`staged_outputs` makes a set of files appear
together, :func:`staged_directory` a whole directory.
"""
from __future__ import annotations

import contextlib
import os
import tempfile
from glob import escape as glob_escape
from pathlib import Path

import numpy as np

from mi_loop.errors import fail

__all__ = ["STAGING", "atomic_open", "ensure_writable_dir", "first_missing_ancestor", "remove_if_empty",
           "png_bytes", "remove_stale_stages", "staged_directory", "staged_outputs", "write_png", "write_text"]


def first_missing_ancestor(path) -> Path | None:
    """Return the outermost directory of ``path`` (itself included) that does not exist yet.

    Parameters
    ----------
    path : str or os.PathLike
        A directory about to be created.

    Returns
    -------
    pathlib.Path or None
        Absolute; None when ``path`` exists.

    Examples
    --------
    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as d:
    ...     first_missing_ancestor(Path(d) / "a" / "b") == Path(d).absolute() / "a"
    True
    """
    path = Path(path).absolute()
    missing = None
    for p in [path, *path.parents]:
        if p.exists():
            break
        missing = p
    return missing


def remove_if_empty(top: Path | None, path) -> None:
    """Remove ``path`` and its parents up to ``top`` when they are empty (after a failed run).

    Parameters
    ----------
    top : pathlib.Path or None
        The outermost directory the run created (:func:`first_missing_ancestor`);
        None removes nothing.
    path : str or os.PathLike
        The output directory.
    """
    if top is None:
        return
    path = Path(path).absolute()
    for p in [path, *path.parents]:
        with contextlib.suppress(OSError):
            p.rmdir()
        if p == top:
            break


@contextlib.contextmanager
def staged_outputs(outdir):
    """Yield a hidden staging directory in ``outdir``; on success move its files into ``outdir``.

    All outputs of a run appear together (each move is atomic); on failure the
    staging directory is removed and ``outdir`` keeps what it had.

    Parameters
    ----------
    outdir : str or os.PathLike
        An existing, writable directory.

    Yields
    ------
    pathlib.Path
        The staging directory: write the outputs there.
    """
    import shutil

    outdir = Path(outdir)
    stage = Path(tempfile.mkdtemp(prefix=".staging-", dir=outdir))
    try:
        yield stage
        for f in sorted(stage.iterdir()):
            os.replace(f, outdir / f.name)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


#: Name prefix of :func:`staged_directory`'s staging directories, after ``.`` and the directory's name.
STAGING = ".staging-"


@contextlib.contextmanager
def staged_directory(path):
    """Yield a hidden sibling directory of ``path`` that becomes ``path`` when the block succeeds.

    The directory appears whole or not at all: on success the sibling is
    renamed to ``path`` (an existing directory there is moved aside first, then
    removed); on failure it is removed and ``path`` stays as it was.

    Parameters
    ----------
    path : str or os.PathLike
        The directory to produce; its parent must exist.

    Yields
    ------
    pathlib.Path
        The staging directory ``.<name>.staging-XXXXXXXX`` beside ``path``: write everything there.

    Examples
    --------
    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as d:
    ...     with staged_directory(Path(d) / "out") as stage:
    ...         _ = write_text(stage / "a.txt", "a")
    ...     sorted(p.name for p in Path(d).rglob("*"))
    ['a.txt', 'out']
    """
    import shutil

    path = Path(path)
    stage = Path(tempfile.mkdtemp(prefix=f".{path.name}{STAGING}", dir=path.parent))
    try:
        os.chmod(stage, 0o777 & ~_umask())       # mkdtemp makes 0700 directories
        yield stage
        if not path.is_dir():
            os.replace(stage, path)
            return
        old = Path(tempfile.mkdtemp(prefix=f".{path.name}.old-", dir=path.parent))
        try:
            os.replace(path, old / path.name)
            try:
                os.replace(stage, path)
            except BaseException:
                os.replace(old / path.name, path)       # put the old one back
                raise
        finally:
            shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def remove_stale_stages(path) -> list:
    """Remove the staging directories that interrupted :func:`staged_directory` blocks left beside ``path``.

    Parameters
    ----------
    path : str or os.PathLike
        The directory they were staging.

    Returns
    -------
    list of pathlib.Path
        The directories removed.
    """
    import shutil

    path = Path(path)
    stale = sorted(path.parent.glob(f".{glob_escape(path.name)}{STAGING}*"))
    for p in stale:
        shutil.rmtree(p, ignore_errors=True)
    return stale


def ensure_writable_dir(path) -> Path:
    """Create a directory if needed and check that files can be created in it.

    Parameters
    ----------
    path : str or os.PathLike
        Directory to create (with parents) and probe.

    Returns
    -------
    pathlib.Path
        The directory.

    Raises
    ------
    ValueError
        If the directory cannot be created or written to; the message names
        the path and the operating system's reason.
    """
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as exc:
        fail("ensure_writable_dir", "a directory that files can be created in",
             f"'{path}': {exc.strerror or exc}")
    return path


def _file_mode(path: Path) -> int:
    """Permissions for ``path``: those of the file it replaces, else 0666 less the umask."""
    try:
        return path.stat().st_mode & 0o7777
    except OSError:
        return 0o666 & ~_umask()


def _umask() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return umask


@contextlib.contextmanager
def atomic_open(path):
    """Yield a binary file in ``path``'s directory that replaces ``path`` on success.

    Parameters
    ----------
    path : str or os.PathLike
        Destination; its directory must exist. An existing file keeps its permissions.

    Yields
    ------
    file object
        Open for binary writing; on an exception it is deleted and ``path`` is untouched.
    """
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
    try:
        with os.fdopen(fd, "wb") as f:
            yield f
        os.chmod(tmp, _file_mode(path))       # mkstemp makes 0600 files
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _png(image, func: str) -> bytes:
    """The PNG bytes of ``image``, checked; errors name ``func``."""
    import io

    from matplotlib import image as mpl_image

    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] not in (3, 4) or 0 in image.shape:
        fail(func, "an (h, w, 3|4) image", f"shape {image.shape}")
    if image.dtype != np.uint8:
        bad = ~((image >= 0) & (image <= 1))
        if bad.any():
            fail(func, "float pixels in [0, 1] (no NaN)",
                 f"{image[bad].flat[0]} at pixel {np.argwhere(bad)[0, :2].tolist()}")
        image = np.round(image * 255).astype(np.uint8)
    buffer = io.BytesIO()
    mpl_image.imsave(buffer, image, format="png")
    return buffer.getvalue()


def png_bytes(image) -> bytes:
    """Encode an RGB(A) image as an 8-bit PNG file's bytes (for a page that embeds it).

    Parameters
    ----------
    image : (h, w, 3) or (h, w, 4) array-like, uint8 or float
        Display-ready pixels: uint8, or floats in [0, 1] (already
        gamma-encoded; see :func:`mi_loop.render.scene.to_srgb`).

    Returns
    -------
    bytes
        The PNG file.

    Raises
    ------
    ValueError
        If the image is not (h, w, 3|4) or a float image has values outside
        [0, 1] or NaNs.

    Examples
    --------
    >>> png_bytes(np.zeros((2, 3, 3), np.uint8))[:8]
    b'\\x89PNG\\r\\n\\x1a\\n'
    """
    return _png(image, "png_bytes")


def write_png(path, image) -> Path:
    """Write an RGB(A) image as an 8-bit PNG file, atomically (:func:`png_bytes`).

    Parameters
    ----------
    path : str or os.PathLike
        Destination; its directory must exist.
    image : (h, w, 3) or (h, w, 4) array-like, uint8 or float
        Display-ready pixels: uint8, or floats in [0, 1] (already
        gamma-encoded; see :func:`mi_loop.render.scene.to_srgb`).

    Returns
    -------
    pathlib.Path
        The written path.

    Raises
    ------
    ValueError
        If the image is not (h, w, 3|4) or a float image has values outside
        [0, 1] or NaNs.
    """
    data = _png(image, "write_png")
    path = Path(path)
    with atomic_open(path) as f:
        f.write(data)
    return path


def write_text(path, text: str) -> Path:
    """Write a UTF-8 text file (e.g. JSON), atomically.

    Parameters
    ----------
    path : str or os.PathLike
        Destination; its directory must exist.
    text : str
        Content.

    Returns
    -------
    pathlib.Path
        The written path.
    """
    path = Path(path)
    with atomic_open(path) as f:
        f.write(text.encode("utf-8"))
    return path
