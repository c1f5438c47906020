"""Run a block of Dr.Jit work on one LLVM thread, for bit-reproducible results where atomics remain.

mi_loop's own reverse passes are free of atomics (:mod:`mi_loop.ad.sparse`).
Mitsuba's reverse render is not: each ray scatters its adjoint into the
vertex buffer with atomic adds, whose order changes from run to run when
several threads run the kernel. :func:`one_thread` runs a block on one thread
of the LLVM backend, where those adds happen in a fixed order. The CUDA
backend is unaffected (its atomics are not ordered; there is no equivalent).
"""
from __future__ import annotations

import contextlib

__all__ = ["one_thread"]


@contextlib.contextmanager
def one_thread(enabled: bool = True):
    """Context manager: the LLVM backend runs kernels on one thread inside the block.

    Parameters
    ----------
    enabled : bool, optional
        When False the block runs unchanged (so callers can write
        ``with one_thread(options.deterministic):``).

    Examples
    --------
    >>> import drjit as dr, mitsuba as mi, mi_loop
    >>> mi_loop.set_variant("llvm_ad_rgb")
    >>> before = dr.thread_count()
    >>> with one_thread():
    ...     inside = dr.thread_count()
    >>> inside, dr.thread_count() == before
    (1, True)
    """
    if not enabled:
        yield
        return
    import drjit as dr

    before = dr.thread_count()
    dr.sync_thread()                 # work queued so far runs with the previous thread count
    dr.set_thread_count(1)
    try:
        yield
        dr.sync_thread()
    finally:
        dr.set_thread_count(before)
