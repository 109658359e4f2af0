"""The contact validation's real-cell path: MotoROS driver against the fake controller, probe on a CAN bus.

The fake controller runs in this process (its arms are the cell's physics here); a probe thread touches while the
nominal gun tip is within 1 mm of the plan's contact point, sending real CAN frames on python-can's virtual bus
that the command's :class:`~drivers.can_probe.CanContactProbe` reads.
"""

from __future__ import annotations

import json
import socket
import threading
from pathlib import Path

import numpy as np
import yaml

from app.cli.commands import main
from app.collection.rehearsal import write_rehearsal_cell
from app.dual.validate import relative_position
from calibration.models import ConstantModel
from cell_config import load_cell
from drivers.motoros.fake_cell import build_fake_controller
from drivers.sim.can_probe import SimulatedProbe


class NominalContact:
    """Touches while the nominal gun tip is within ``tol_mm`` of the contact point (the fake arms' physics)."""

    def __init__(self, cell, fake, probe, p_contact: np.ndarray, tol_mm: float = 1.0) -> None:  # noqa: ANN001
        self.cell, self.fake, self.probe, self.p, self.tol = cell, fake, probe, p_contact, tol_mm
        self.models = {k: ConstantModel(k, "nominal", cell.robot(k).model()) for k in ("R1", "R2")}
        self.stop = threading.Event()
        self.touching = False
        self.thread = threading.Thread(target=self.run, daemon=True)

    def run(self) -> None:
        while not self.stop.wait(0.005):
            q = np.concatenate([self.fake.q(0), self.fake.q(1)])[None]
            d = float(np.linalg.norm(relative_position(self.cell, self.models["R1"].fk, self.models["R2"].fk, q)[0]
                                     - self.p))
            if (d <= self.tol) != self.touching:
                self.touching = not self.touching
                self.probe.touch() if self.touching else self.probe.release()


def test_validate_dual_on_the_real_path_drives_the_plan_and_reads_the_probe(tmp_path: Path, capsys) -> None:
    cell_path = write_rehearsal_cell(tmp_path)
    data = yaml.safe_load(cell_path.read_text())
    data["probe"]["channel"] = f"validate-{tmp_path.name}"
    cell_path.write_text(yaml.safe_dump(data, sort_keys=False))
    plan = tmp_path / "plan.json"
    assert main(["--cell", str(cell_path), "plan-dual", "--path", "sweep:4", "--no-compile", "--out", str(plan)]) == 0
    cell = load_cell(cell_path)
    p_contact = np.asarray(json.loads(plan.read_text())["T_wp_gun"], dtype=float)[:3, 3]
    from app.collection.runtime.sim import park_q

    fake = build_fake_controller(cell, initial_q={n: park_q(n) for n in ("R1", "R2")})
    with fake, SimulatedProbe(cell.probe.channel, heartbeat_period_s=0.02, base_id=cell.probe.base_id) as sim_probe:
        contact = NominalContact(cell, fake, sim_probe, p_contact)
        contact.thread.start()
        try:
            code = main(["--cell", str(cell_path), "validate-dual", "--plan", str(plan), "--yes", "--speed", "1",
                         "--json", str(tmp_path / "val.json")])
        finally:
            contact.stop.set()
            contact.thread.join(timeout=2)
    out = capsys.readouterr()
    assert code == 0, out.err
    result = json.loads((tmp_path / "val.json").read_text())
    assert result["configurations"] == 4 and result["unconfirmed"] == 0
    assert result["models"]["nominal"]["max_mm"] < 1.0  # the probe touched within 1 mm of the nominal tip


def test_validate_dual_real_needs_a_plan_and_a_probe(tmp_path: Path, capsys) -> None:
    from tests.conftest import assert_bad_input

    cell_path = write_rehearsal_cell(tmp_path)
    assert_bad_input(capsys, ["--cell", str(cell_path), "validate-dual"], "needs --plan")
    data = yaml.safe_load(cell_path.read_text())
    del data["probe"]
    cell_path.write_text(yaml.safe_dump(data, sort_keys=False))
    assert_bad_input(capsys, ["--cell", str(cell_path), "validate-dual", "--plan", str(tmp_path / "p.json")],
                     "no probe block")



def test_rehearsal_ports_are_picked_with_every_socket_bound() -> None:
    # Picked one after the other, the controller's motion and state ports once came out the same (36511) and
    # plan-dual refused the rehearsal cell; free_ports keeps every socket bound until all are picked.
    from app.collection.rehearsal import free_ports

    ports = free_ports(*[socket.SOCK_STREAM] * 50, socket.SOCK_DGRAM)
    assert len(ports) == 51 and len(set(ports[:50])) == 50 and all(0 < p < 65536 for p in ports)
