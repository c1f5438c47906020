"""The application: jobs that read inputs, run a fit and write its outputs, their pictures, the CLI.

- :mod:`~mi_loop.app.cli`: ``mi-loop``, the only module that parses arguments;
- :mod:`~mi_loop.app.fit_job`, :mod:`~mi_loop.app.sequence_job`: ``fit``/``compare`` and ``fit-sequence``;
- :mod:`~mi_loop.app.report`: loss plots, side-by-side renders, drift plots.
"""
