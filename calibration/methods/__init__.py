"""The calibration methods: the fitter (``fitter``), its options (``options``), the families (``pi``, ``cdc``), the
held-out checks (``heldout``), the workspace probes (``workspace``), the recommendation (``recommend``) and the
top-up design (``topup``). The method names themselves are :mod:`calibration.method_names`."""
