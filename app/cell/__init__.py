"""One arm's calibration session on the cell: plans and the plan file (:mod:`~app.cell.planning`,
:mod:`~app.cell.session_plan`, :mod:`~app.cell.plan_file`), safety (:mod:`~app.cell.capsules`,
:mod:`~app.cell.safety`, :mod:`~app.cell.motion`, :mod:`~app.cell.dry_run`), collection and sessions
(:mod:`~app.cell.collect`, :mod:`~app.cell.session_store`, :mod:`~app.cell.mocap_window`), the cell at run
time, simulated or real (:mod:`~app.cell.runtime`, :mod:`~app.cell.real_cell`, :mod:`~app.cell.mocap_service`),
frame registration (:mod:`~app.cell.register`) and the end-to-end rehearsal against fake devices
(:mod:`~app.cell.rehearsal`)."""
