"""``cellcal demo``: the whole workflow on the simulated cell (:mod:`~app.demo.run`) and its HTML report
(:mod:`~app.demo.report`)."""
