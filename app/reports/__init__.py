"""Reports: the HTML page (``page``), acceptance against a tolerance (``acceptance``), the sections of the
comparison, evaluation and demo reports (``sections``), plots, the diagnosis report, provenance, the sign-off
verdict and the warnings a command gave."""
