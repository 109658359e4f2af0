"""The meshcat preview of a dual plan: the page (``page``), the plan read for it (``plan``), the scene, the
readout and the local meshcat server."""
