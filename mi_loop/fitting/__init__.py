"""Fitting loops (no file I/O): templates, static fits, frame-by-frame sequence fits.

- :mod:`~mi_loop.fitting.options`: :class:`FitOptions`, :class:`SequenceOptions`, the one vocabulary of options;
- :mod:`~mi_loop.fitting.template`, :mod:`~mi_loop.fitting.slivers`: automatic control-mesh templates;
- :mod:`~mi_loop.fitting.static`: :func:`fit`, IMLS + coverage + ARAP with Adam;
- :mod:`~mi_loop.fitting.sequence`: :func:`fit_frame`, the same plus the multi-view image term.
"""
from __future__ import annotations

from mi_loop.fitting.options import FitOptions, SequenceOptions
from mi_loop.fitting.static import fit

__all__ = ["FitOptions", "SequenceOptions", "fit"]
