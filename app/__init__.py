"""Workflows and the command-line interface, by room: :mod:`app.cli` (the ``cellcal`` command line),
:mod:`app.workflows` (fit, compare, diagnose, recalibrate, the demo, init-cell), :mod:`app.reports` (the report
pages, acceptance, plots, provenance), :mod:`app.collection` (plans, safety, collection, sessions, registration,
the cell at run time), :mod:`app.dual` (dual planner, paths, export, preview, validation) and :mod:`app.jobs`
(controller jobs)."""
