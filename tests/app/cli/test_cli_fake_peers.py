"""The rehearsal's fake peers as processes: a port already taken is one line on stderr, exit 2."""

from __future__ import annotations

import socket

import yaml

from app.collection.rehearsal import run_cellcal, write_rehearsal_cell


def _one_line(result) -> str:
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2 and len(lines) == 1, (result.returncode, result.stderr)
    return lines[0]


def test_fake_controller_on_a_taken_port_is_one_line(tmp_path):
    cell = write_rehearsal_cell(tmp_path)
    port = yaml.safe_load(cell.read_text())["controller"]["state_port"]
    with socket.create_server(("127.0.0.1", port)):  # another fake controller (or anything) holds it
        line = _one_line(run_cellcal(cell, "fake-controller", timeout_s=30))
    assert line.startswith("cellcal fake-controller: ") and f"state port {port}" in line, line
    assert "Traceback" not in line


def test_fake_motive_on_a_taken_port_is_one_line(tmp_path):
    cell = write_rehearsal_cell(tmp_path)
    port = yaml.safe_load(cell.read_text())["mocap"]["command_port"]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:  # another fake Motive holds it
        taken.bind(("127.0.0.1", port))
        line = _one_line(run_cellcal(cell, "fake-motive", timeout_s=30))
    assert line.startswith("cellcal fake-motive: ") and f"command port {port}" in line, line
