"""Workflows and the command-line interface."""
