"""A command whose standard output is closed early (``cellcal ... | head``) exits quietly: no BrokenPipeError
traceback, and the closed pipe changes nothing but where the rest of the text goes (the command finishes, its files
written, its own exit status), whether the error would come at a print (unbuffered) or at the last flush (a pipe is
block-buffered). Only a closed stdout is taken for that: a BrokenPipeError from anything else (a socket whose peer
left) still propagates."""

from __future__ import annotations

import io
import os
import subprocess
import sys
from pathlib import Path

import pytest

from app.cli import commands
from app.cli.commands import build_parser, main
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.models import ConstantModel, save_model
from cell_config import load_cell
from tests.conftest import planted_parameters

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    path = tmp_path_factory.mktemp("closed_stdout") / "R1.yaml"
    par = MinimalParameterisation(load_cell().robot("R1").model(), fit_tool=True)
    save_model(ConstantModel("R1", "nls1", par.model(planted_parameters(par)), par.size), path)
    return path


@pytest.fixture
def closed_stdout(monkeypatch):
    """Put sys.stdout on a new pipe whose reader has gone (one per call: main points a closed one at the null
    device). Block-buffered, the error comes at main's last flush; line-buffered, at the command's first print."""
    streams = []

    def close(line_buffering: bool) -> None:
        read, write = os.pipe()
        os.close(read)
        streams.append(io.TextIOWrapper(io.FileIO(write, "w"), line_buffering=line_buffering))
        monkeypatch.setattr(sys, "stdout", streams[-1])

    yield close
    monkeypatch.undo()
    for stream in streams:
        stream.close()  # the rest of the buffer goes to the null device


def subcommands() -> list[str]:
    parser = build_parser()
    action = next(a for a in parser._actions if a.choices and "fit" in a.choices)
    return sorted(action.choices)


@pytest.mark.parametrize("line_buffering", [False, True], ids=["block-buffered", "line-buffered"])
def test_every_commands_help_into_a_closed_pipe_exits_0_quietly(closed_stdout, line_buffering):
    for argv in (["--help"], ["--version"], *([name, "--help"] for name in subcommands())):
        closed_stdout(line_buffering)
        with pytest.raises(SystemExit) as stop:
            main(argv)
        assert stop.value.code == 0, argv
        assert sys.stdout is not None and not isinstance(sys.stdout, commands._StdoutGuard)  # given back


@pytest.mark.parametrize("line_buffering", [False, True], ids=["block-buffered", "line-buffered"])
@pytest.mark.parametrize("command", ["export-urdf", "init-cell"])
def test_a_command_into_a_closed_pipe_finishes_as_it_would_have(command, line_buffering, model, closed_stdout,
                                                                 tmp_path):
    out = tmp_path / "out"
    argv, written = {
        "export-urdf": (["export-urdf", "--model", str(model), "--out", str(out / "r1.urdf"), "--xacro",
                         str(out / "r1.xacro")], ["r1.urdf", "r1.xacro"]),
        "init-cell": (["init-cell", str(out)], ["cell.yaml", "robots", "tools"])}[command]
    closed_stdout(line_buffering)
    assert main(argv) == 0
    assert sorted(p.name for p in out.iterdir()) == written


def test_a_broken_pipe_that_is_not_stdout_still_propagates(monkeypatch):
    def peer_left(argv):
        raise BrokenPipeError(32, "Broken pipe")  # e.g. a controller socket; stdout (pytest's capture) is open

    monkeypatch.setattr(commands, "_run", peer_left)
    with pytest.raises(BrokenPipeError):
        main(["--version"])


@pytest.mark.parametrize("unbuffered", ["", "1"], ids=["buffered", "PYTHONUNBUFFERED"])
def test_the_entry_point_piped_into_a_gone_reader_prints_no_traceback(unbuffered, model, tmp_path):
    """The real entry point (``python -m app.cli`` runs the ``cellcal`` script's main) in a process, so the
    interpreter's own final flush is covered: it ended in a BrokenPipeError traceback (exit 120, or 1 unbuffered)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"} | (
        {"PYTHONUNBUFFERED": unbuffered} if unbuffered else {})
    proc = subprocess.Popen([sys.executable, "-m", "app.cli", "export-urdf", "--model", str(model), "--out",
                             str(tmp_path / "r1.urdf")], stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT,
                            env=env)
    proc.stdout.close()  # the reader goes before the command prints, as `| head -0` or `| true` would
    stderr = proc.stderr.read().decode()
    proc.wait(timeout=60)
    proc.stderr.close()
    assert (proc.returncode, stderr) == (0, "")
    assert (tmp_path / "r1.urdf").exists()
