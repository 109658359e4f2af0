"""The collection plan kind: the targets (:class:`Target`) an arm visits and the plan that lists them
(:class:`Plan`)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from app.collection.plans.schema import PLAN_SCHEMA as SCHEMA
from app.collection.plans.schema import json_numbers
from calibration.data.files import atomic_write_text
from calibration.errors import DataError

TargetKind = Literal["anchor", "perturb", "cpa", "validation"]


KINDS: tuple[str, ...] = ("anchor", "perturb", "cpa", "validation")


VALIDATION_CLUSTER = -1


@dataclass(frozen=True)
class Target:
    """One pose to visit.

    Attributes:
        robot: robot name (``R1``).
        q: joint angles [rad], shape (6,).
        cluster: cluster id (anchor index; CPA sweeps continue after the anchors; -1 for validation).
        kind: ``anchor``, ``perturb`` (anchor + 1 deg on one joint), ``cpa`` or ``validation``.
    """

    robot: str
    q: np.ndarray
    cluster: int
    kind: TargetKind

    def to_dict(self) -> dict[str, Any]:
        return {"robot": self.robot, "q_rad": [float(v) for v in self.q], "cluster": self.cluster,
                "kind": self.kind}


@dataclass(frozen=True)
class Plan:
    """An ordered list of targets plus the parameters that produced it.

    Attributes:
        targets: the targets in visiting order.
        params: how the plan was built (kept in the file for the record).
    """

    targets: tuple[Target, ...]
    params: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.targets)

    @property
    def q(self) -> np.ndarray:
        """All target joint angles [rad], shape (N, 6)."""
        return np.array([t.q for t in self.targets]).reshape(-1, 6)

    @property
    def robots(self) -> tuple[str, ...]:
        """Robot names in the plan, in order of first appearance."""
        return tuple(dict.fromkeys(t.robot for t in self.targets))

    def to_dict(self) -> dict[str, Any]:
        return {"schema": SCHEMA, "kind": "collection", "params": self.params, "targets": [t.to_dict() for t in self.targets]}

    @staticmethod
    def from_dict(d: Any, source: str = "<plan>") -> Plan:
        """Validate and build a plan from its JSON form; raises DataError naming the bad entry."""
        if not isinstance(d, dict) or d.get("schema") != SCHEMA:
            raise DataError(source, None, "schema", f"expected schema {SCHEMA!r}")
        raw = d.get("targets")
        if not isinstance(raw, list):
            raise DataError(source, None, "targets", "expected a list of targets")
        targets = []
        for i, t in enumerate(raw):
            where = f"targets[{i}]"
            if not isinstance(t, dict) or not {"robot", "q_rad", "cluster", "kind"} <= set(t):
                raise DataError(source, None, where, "expected robot, q_rad, cluster and kind")
            q = json_numbers(t["q_rad"])
            if q is None or q.shape != (6,) or not np.all(np.isfinite(q)):
                raise DataError(source, None, where + ".q_rad", f"expected 6 finite numbers, got {t['q_rad']!r}")
            if t["kind"] not in KINDS:
                raise DataError(source, None, where + ".kind", f"expected one of {', '.join(KINDS)}, got {t['kind']!r}")
            if not isinstance(t["cluster"], int) or isinstance(t["cluster"], bool) or not isinstance(t["robot"], str):
                raise DataError(source, None, where, "expected an integer cluster and a robot name")
            targets.append(Target(t["robot"], q, t["cluster"], t["kind"]))
        return Plan(tuple(targets), dict(d.get("params") or {}))

    def save(self, path: str | Path) -> None:
        """Write the plan as JSON, atomically (a failed write leaves the old file, never a cut-off one)."""
        atomic_write_text(path, json.dumps(self.to_dict(), indent=1) + "\n")
