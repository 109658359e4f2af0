"""The calibration methods. A method is a function registered under its name in :mod:`~calibration.methods.registry`
by its family's module: ``constant`` (nominal, base, cpa, nls0, nls1), ``pi``, ``cdc_fit`` (every CDC name, over the
local cluster fits of ``cdc``) and ``diagnosed``. They fit on :class:`~calibration.methods.shared.SharedFits` (the
fits methods share, made once, in a typed cache) with the held-out refits of ``folds``; ``fitter.Fitter`` is the
facade that looks a method up and fits it. Beside them: the options (``options``), the held-out checks
(``heldout``), the workspace probes (``workspace``), the recommendation (``recommend``) and the top-up design
(``topup``). The method names themselves are :mod:`calibration.method_names`."""
