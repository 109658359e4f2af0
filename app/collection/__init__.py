"""One arm's calibration session on the cell: plans and the plan file (:mod:`~app.collection.plans.poses`,
:mod:`~app.collection.plans.session`, :mod:`~app.collection.plans.reader`), safety (:mod:`~cell_config.capsules`,
:mod:`~app.collection.safety`, :mod:`~app.collection.motion`, :mod:`~app.collection.dry_run`), collection and sessions
(:mod:`~app.collection.collect`, :mod:`~app.collection.session_store`, :mod:`~app.collection.mocap_window`), the cell at run
time, simulated or real (:mod:`~app.collection.runtime.sim`, :mod:`~app.collection.runtime.real`, :mod:`~app.collection.mocap_bridge`),
frame registration (:mod:`~app.collection.register`) and the end-to-end rehearsal against fake devices
(:mod:`~app.collection.rehearsal`)."""
