"""``cellcal demo``: the whole workflow on the simulated cell (:mod:`~app.demo.run`); its HTML report is
:func:`app.analysis.report.write_demo_report`."""
