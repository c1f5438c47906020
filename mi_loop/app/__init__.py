"""The application: jobs that read inputs, run a fit and write its outputs, their pictures, the CLI.

- :mod:`~mi_loop.app.cli`: ``mi-loop``, the only module that parses arguments
  (:mod:`~mi_loop.app.parser` builds the parser; defaults from :mod:`mi_loop.fitting.options`);
- the jobs, one ``*_job`` module per command, each importing shared modules only (``fit-batch`` runs
  the ``run`` of ``fit`` and ``fit-sequence``, as the CLI does):
  :mod:`~mi_loop.app.fit_job`, :mod:`~mi_loop.app.images_job`, :mod:`~mi_loop.app.sequence_job`,
  :mod:`~mi_loop.app.compare_job`, :mod:`~mi_loop.app.export_job`, :mod:`~mi_loop.app.batch_job`;
- ``fit-sequence`` top-down: :mod:`~mi_loop.app.sequence_sources` (photos, reference),
  :mod:`~mi_loop.app.sequence_start` (the options as run, template, visual hull, start or resume),
  :mod:`~mi_loop.app.sequence_frames` (the frame loop; :class:`~mi_loop.app.sequence_frames.FrameFitter`
  is its one caller of :mod:`mi_loop.fitting` and :mod:`mi_loop.render` for the frames),
  :mod:`~mi_loop.app.sequence_pictures` (``drift.png``, ``strip.png``, ``report.html``);
- :mod:`~mi_loop.app.results`: result directories and the viewer tessellations the jobs and ``export`` share;
- :mod:`~mi_loop.app.cluster`, :mod:`~mi_loop.app.batch_summary`: where ``fit-batch`` runs, its ``summary.csv``;
- :mod:`~mi_loop.app.inputs`: inputs as fitting data (normals, templates checked against the data,
  frames as :class:`~mi_loop.app.inputs.FitFrame`);
- :mod:`~mi_loop.app.progress`: progress lines and bars, warnings, written paths;
- :mod:`~mi_loop.app.report`, :mod:`~mi_loop.app.image_report`: loss plots, drift plots, side-by-side
  renders, photo grids (pixel arrays);
- :mod:`~mi_loop.app.html_report`: ``report.html``, self-contained pages with a three.js view (``viewer/``),
  from what :mod:`~mi_loop.app.report_data` computes (distances per limit point, crease curves, frusta).

Files are opened by :mod:`mi_loop.io` only (the run files of a sequence through :mod:`mi_loop.io.runs`,
the viewer's files through :func:`mi_loop.io.read_package_text`).
"""

__all__: list = []
