"""Data in and out: recordings (``recording``), atomic output files and locks (``files``), YAML (``yamlio``)."""
