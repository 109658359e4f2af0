"""Analysis workflows on recordings and models: fitting an arm of the cell (:mod:`~app.analysis.fitting`),
comparing methods (:mod:`~app.analysis.compare`), the HTML/JSON reports (:mod:`~app.analysis.report`), the
diagnosis workflow (:mod:`~app.analysis.diagnose`) and recalibration of the model in service
(:mod:`~app.analysis.recalibrate`)."""
