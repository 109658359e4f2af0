"""``register``'s hint when R2's registered base differs from the cell file's by millimetres: it names the file and
key and gives the block that, pasted there, makes the cell file agree with the registration."""

from __future__ import annotations

import numpy as np

from app.collection.register import base_update_hint, relative_bases
from app.workflows.init_cell import init_cell
from calibration.kinematics import so3
from cell_config import load_cell
from cell_config.registration import RobotRegistration


def registration(T):
    return RobotRegistration(T, np.eye(4), "2026-12-04T00:00:00+00:00", 0.01, 0.001, 30, np.zeros(6), np.zeros(6))


def registrations_for(cell, dp_mm, drot_rad):
    T_world_cell = np.eye(4)
    T_world_cell[:3, :3], T_world_cell[:3, 3] = so3.exp(np.array([0.1, -0.2, 1.0])), [300.0, -50.0, 900.0]
    T_move = np.eye(4)
    T_move[:3, :3], T_move[:3, 3] = so3.exp(np.array([0.0, 0.0, drot_rad])), dp_mm
    return {"R1": registration(T_world_cell @ cell.robot("R1").T_cell_base),
            "R2": registration(T_world_cell @ cell.robot("R2").T_cell_base @ T_move)}


def test_hint_block_pasted_into_the_cell_file_makes_it_agree(tmp_path):
    written = init_cell(tmp_path / "cell")
    cell = load_cell(written.cell)
    rel = relative_bases(cell, registrations_for(cell, [2.0, -1.5, 0.7], 2e-4))
    hint = base_update_hint(cell, "R2", rel["R2"])
    assert hint is not None and f"in {written.cell}, replace robots.R2.T_cell_base with" in hint
    assert f"cellcal --cell {written.cell} plan-dual" in hint
    block = hint.split("with\n", 1)[1].split("\nthen", 1)[0]
    text = written.cell.read_text()
    r2 = text.index("  R2:")
    start = text.index("    T_cell_base:", r2)
    end = text.index("      - [0, 0, 0, 1]\n", start) + len("      - [0, 0, 0, 1]\n")
    written.cell.write_text(text[:start] + block + "\n" + text[end:])
    updated = load_cell(written.cell)
    after = relative_bases(updated, registrations_for(cell, [2.0, -1.5, 0.7], 2e-4))["R2"]
    assert after["cell_yaml_diff_mm"] < 1e-5 and after["cell_yaml_diff_deg"] < 1e-6, after
    assert base_update_hint(updated, "R2", after) is None


def test_no_hint_within_the_threshold():
    cell = load_cell()
    rel = relative_bases(cell, registrations_for(cell, [0.1, 0.0, -0.1], 1e-5))
    assert rel["R2"]["cell_yaml_diff_mm"] > 0.05
    assert base_update_hint(cell, "R2", rel["R2"]) is None
