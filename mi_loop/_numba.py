"""Numba, with its threading layer chosen before the first parallel kernel runs.

OpenMP first: it is safe to call from several Python threads at once (Dask's
threaded workers), and Numba would otherwise try TBB first and warn that the
TBB pymeshlab loads is too old.
"""
from __future__ import annotations

import numba

numba.config.THREADING_LAYER_PRIORITY = ["omp", "tbb", "workqueue"]

__all__ = ["numba"]
