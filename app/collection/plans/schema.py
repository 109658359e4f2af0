"""What every plan file shares: the schema string, the plan kinds and how a file says which it is
(:func:`plan_kind`), and the strict reading of JSON numbers (:func:`json_numbers`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import numpy as np

from calibration.errors import DataError

PLAN_SCHEMA = "cellcal.plan/1"


PlanKind = Literal["collection", "dual"]


PLAN_KINDS: tuple[str, ...] = ("collection", "dual")


_LAYOUTS = {None: "a plan with 'waypoints' (kind 'dual') or 'targets' (kind 'collection')",
            "dual": "a dual plan with 'waypoints' (from cellcal plan-dual)",
            "collection": "a collection plan with 'targets' (from cellcal plan)"}


def plan_kind(d: Any, source: str | Path = "<plan>", expected: PlanKind | None = None) -> str:
    """The kind of a plan file's content: its ``kind``, or the layout of a file without one.

    Args:
        d: the parsed JSON. source: where it came from (for messages).
        expected: the kind the caller needs, named in the message of a file that is not a plan.

    Raises:
        DataError: not a plan file (wrong schema, unknown kind, neither ``waypoints`` nor ``targets``).
    """
    layout = f"expected {_LAYOUTS[expected]} and schema {PLAN_SCHEMA!r}"
    if not isinstance(d, dict) or d.get("schema") != PLAN_SCHEMA:
        raise DataError(source, None, "schema", layout)
    kind = d.get("kind")
    if kind is None:
        kind = "dual" if isinstance(d.get("waypoints"), list) else "collection" if "targets" in d else None
        if kind is None:
            raise DataError(source, None, None, layout)
    if kind not in PLAN_KINDS:
        raise DataError(source, None, "kind", f"unknown plan kind {kind!r}; valid: {', '.join(PLAN_KINDS)}")
    return str(kind)


def json_numbers(value: Any) -> np.ndarray | None:
    """A (nested) list of JSON numbers as a float array, or None when any entry is not a number: a string ("0.1")
    or a boolean (true, which numpy reads as 1 rad) in a plan file is a mistake, not an angle."""
    def ok(v: Any) -> bool:
        if isinstance(v, list):
            return all(ok(x) for x in v)
        return isinstance(v, (int, float)) and not isinstance(v, bool)

    return np.asarray(value, dtype=float) if isinstance(value, list) and ok(value) else None
