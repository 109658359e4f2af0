"""A named block of a model's parameter vector (:class:`Block`): each model kind declares its blocks once, and the
physics-informed layout (:mod:`calibration.physics.layout`) is a tuple of them."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Block:
    """One named block of a model's parameter vector (a model kind declares its blocks once)."""

    name: str
    names: tuple[str, ...]

    @property
    def size(self) -> int:
        return len(self.names)
