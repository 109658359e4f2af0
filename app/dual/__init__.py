"""The dual-robot cell: the relative-pose planner (:mod:`~app.dual.planner`, on the casadi kinematics of
:mod:`~app.dual.casadi_kinematics`) and ``plan-dual``'s workflow with its safety check (:mod:`~app.dual.plan_dual`),
workpiece paths (:mod:`~app.dual.paths`), the dual plan and its file
(:mod:`~app.collection.plans.dual`), controller targets (:mod:`~app.dual.export_targets`), the meshcat preview
(:mod:`~app.dual.preview.page`) and contact validation, on the simulated cell (:mod:`~app.dual.validate`,
:mod:`~app.dual.sim`) and on the real one (:mod:`~app.dual.validate_real`)."""
