"""The application: jobs that read inputs, run a fit and write its outputs, their pictures, the CLI.

- :mod:`~mi_loop.app.cli`: ``mi-loop``, the only module that parses arguments
  (:mod:`~mi_loop.app.parser` builds the parser; defaults from :mod:`mi_loop.fitting.options`);
- :mod:`~mi_loop.app.fit_job`, :mod:`~mi_loop.app.sequence_job`, :mod:`~mi_loop.app.compare_job`:
  ``fit``, ``fit-sequence`` and ``compare``;
- :mod:`~mi_loop.app.batch_job`: ``fit-batch``, many fits on a Dask cluster
  (:mod:`~mi_loop.app.cluster`), with their ``summary.csv`` (:mod:`~mi_loop.app.batch_summary`);
- :mod:`~mi_loop.app.inputs`: inputs as fitting data (normals, templates checked against the data, frames);
- :mod:`~mi_loop.app.progress`: progress lines and bars, warnings, written paths;
- :mod:`~mi_loop.app.report`: loss plots, drift plots, side-by-side renders (pixel arrays).
- :mod:`~mi_loop.app.html_report`: ``report.html``, self-contained pages with a three.js view (``viewer/``),
  from what :mod:`~mi_loop.app.report_data` computes (distances per limit point, crease curves, frusta).
"""

__all__: list = []
