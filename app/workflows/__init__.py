"""Workflows: fit, compare, diagnose, recalibrate, the demo and init-cell, called by the command line."""
