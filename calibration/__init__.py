"""Math only: kinematic models, identification, interpolation, diagnosis."""
