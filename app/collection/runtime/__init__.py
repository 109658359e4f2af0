"""The cell a collection runs on: the simulated cell (``sim``) and the real one (``real``)."""
