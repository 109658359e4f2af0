"""SimCell and RealCell both implement the :class:`~app.collection.runtime.cell.Cell` Protocol the workflows take.

The conformance is checked by mypy in the product (``app.cli.cell_options.open_runtime`` returns either as a
``Cell``; ``collect_arm``, ``measure_registration``, ``recalibrate`` and ``run_real_validation`` take one) and here:
the assignment to a ``Cell`` below is type-checked with ``mypy tests/app/collection/test_cell_protocol.py``. The test below checks the
same members at run time, on instances, so a member renamed on one class fails here too.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from app.collection.rehearsal import write_rehearsal_cell
from app.collection.runtime.cell import Cell
from app.collection.runtime.real import RealCell
from app.collection.runtime.sim import SimCell
from cell_config import load_cell


def _members() -> set[str]:
    """The Protocol's members: its properties and methods, ``__enter__`` and ``__exit__`` included."""
    return {name for name in vars(Cell) if not name.startswith("_")} | {"__enter__", "__exit__"}


def test_the_protocol_states_what_the_workflows_call() -> None:
    assert _members() == {"cell", "drivers", "body_ids", "frames_received", "park_q", "others", "mocap_for", "open",
                          "close", "__enter__", "__exit__"}


@pytest.mark.parametrize("kind", ["sim", "real"])
def test_sim_and_real_cells_have_every_member_of_the_protocol(kind: str, tmp_path: Path) -> None:
    rt: SimCell | RealCell  # built, not opened: nothing connects
    if kind == "sim":
        rt = SimCell(load_cell())
    else:
        rt = RealCell(load_cell(write_rehearsal_cell(tmp_path)), robots=(), registered=False)
    cell: Cell = rt  # mypy: each class is a Cell
    missing = sorted(m for m in _members() if not hasattr(cell, m))
    assert missing == [], f"{type(rt).__name__} lacks {missing}"
    assert cell.frames_received == 0 and not cell.drivers  # nothing open yet
    assert cell.park_q(next(iter(cell.cell.robots))).shape == (6,)
