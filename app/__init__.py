"""Workflows and the command-line interface, by room: :mod:`app.cli` (the ``cellcal`` command line),
:mod:`app.analysis` (fit, compare, report, diagnose, recalibrate), :mod:`app.cell` (plans, safety,
collection, sessions, the cell at run time), :mod:`app.dual` (dual planner, paths, plan file, export,
preview, validation), :mod:`app.demo` (the simulated end-to-end demo) and :mod:`app.jobs` (controller jobs)."""
