"""The one plan-file reader: a collection plan or a dual plan, chosen by the file's ``kind``.

A plan file is JSON with ``schema: cellcal.plan/1`` and a ``kind``:

* ``collection``: one arm's calibration poses (``targets``: robot, q_rad, cluster, kind), read as an
  :class:`app.collection.plans.collection.Plan` (written by ``cellcal plan``);
* ``dual``: both arms per waypoint (``waypoints``: R1, R2 [rad], converged, ...), read as an
  :class:`app.collection.plans.dual.PlanResult` (written by ``cellcal plan-dual``).

A file without ``kind`` (written before it was recorded) is told apart by its layout: ``waypoints`` is a
dual plan, ``targets`` a collection plan. :func:`read_plan` is what every command and workflow reads a plan
with (collect, export, preview, validate, the rehearsal); each kind's own ``from_dict`` checks its entries.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, overload

from app.collection.plans.collection import Plan
from app.collection.plans.dual import PlanResult
from app.collection.plans.schema import _LAYOUTS, PlanKind, plan_kind
from calibration.data.files import read_input_text
from calibration.errors import DataError

if TYPE_CHECKING:

    from app.collection.plans.collection import Plan
    from app.collection.plans.dual import PlanResult

#: Largest plan file read [bytes]. A dual plan holds about 1 kB a waypoint as plan-dual writes it, so 128 MiB is
#: beyond the path readers' 100,000 waypoints; a larger file (a 480 MB plan had export-targets and preview work for
#: minutes), a FIFO or a device is refused before it is read.
MAX_PLAN_BYTES = 128 * 2**20
#: Most waypoints or targets a plan file may hold: the path readers' limit (app.dual.paths.MAX_WAYPOINTS); a
#: collection plan is a few thousand targets.
MAX_PLAN_ENTRIES = 100_000


def plan_from_data(d: Any, source: str | Path = "<plan>", kind: PlanKind | None = None) -> Plan | PlanResult:
    """A plan from a plan file's content, by its kind.

    Args:
        d: the parsed JSON.
        source: where it came from (for messages).
        kind: the kind the caller needs; another kind is refused (None: either).

    Raises:
        DataError: not a plan, not of ``kind``, or a malformed entry (the message names it).
    """

    found = plan_kind(d, source, kind)
    if kind is not None and found != kind:
        raise DataError(source, None, "kind", f"this is a {found} plan; expected {_LAYOUTS[kind]}")
    entries = d.get("waypoints" if found == "dual" else "targets")
    if isinstance(entries, list) and len(entries) > MAX_PLAN_ENTRIES:
        raise DataError(source, None, "waypoints" if found == "dual" else "targets",
                        f"{len(entries)} entries, more than the limit of {MAX_PLAN_ENTRIES}; split the plan")
    return PlanResult.from_dict(d, source) if found == "dual" else Plan.from_dict(d, str(source))


PlanSource = str | Path | dict[str, Any] | Plan | PlanResult


@overload
def read_plan(source: PlanSource, kind: Literal["collection"]) -> Plan: ...
@overload
def read_plan(source: PlanSource, kind: Literal["dual"]) -> PlanResult: ...
@overload
def read_plan(source: PlanSource, kind: None = None) -> Plan | PlanResult: ...


def read_plan(source: PlanSource, kind: PlanKind | None = None) -> Plan | PlanResult:
    """Read a plan file (or take parsed content or a plan object) as a :class:`Plan` or :class:`PlanResult`.

    Args:
        source: a path, the parsed JSON, or an already built plan (returned as it is, kind checked).
        kind: the kind the caller needs (None: either).

    Raises:
        DataError: missing or unreadable file, not JSON, not a plan, another kind, or a malformed entry.
    """

    if isinstance(source, (Plan, PlanResult)):
        found = "dual" if isinstance(source, PlanResult) else "collection"
        if kind is not None and found != kind:
            raise DataError("<plan>", None, "kind", f"this is a {found} plan; expected a {kind} plan")
        return source
    if isinstance(source, dict):
        return plan_from_data(source, "<plan>", kind)
    path = Path(source)
    try:
        d = json.loads(read_input_text(path, MAX_PLAN_BYTES))
    except RecursionError:
        raise DataError(path, None, None, "not a plan file (JSON nested too deep)") from None
    except FileNotFoundError:
        raise DataError(path, None, None, "plan file not found") from None
    except IsADirectoryError:
        raise DataError(path, None, None, "is a folder, expected a plan file (JSON)") from None
    except OSError as e:
        raise DataError(path, None, None, f"cannot read the plan file ({e.strerror or e})") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise DataError(path, None, None, f"not valid JSON ({e})") from None
    try:
        return plan_from_data(d, path, kind)
    except RecursionError:  # a deeply nested entry, read by a recursive check
        raise DataError(path, None, None, "not a plan file (an entry nested too deep)") from None


def read_arm_plan(path: str | Path, robot: str) -> Plan:
    """A collection plan file that moves ``robot`` only (``collect --plan``, ``recalibrate --plan``).

    Raises:
        DataError: what :func:`read_plan` refuses, a dual plan, or a plan that moves another arm (or none).
    """
    plan = read_plan(path, "collection")
    if plan.robots != (robot,):
        raise DataError(path, None, "targets", f"the plan moves {', '.join(plan.robots) or 'nothing'}, "
                                               f"expected {robot} only")
    return plan
