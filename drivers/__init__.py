"""Everything that talks to a device or a network."""
