"""``--cell`` is accepted before and after the command name by every command that reads the cell file."""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import pytest

import cell_config
from app.cli.commands import build_parser, main
from calibration.errors import CellCalError
from tests.conftest import assert_bad_input

#: Commands that never read the cell file (they take no --cell after their name; init-cell copies the packaged one).
NO_CELL = ("export", "init-cell")


class CellLoaded(CellCalError):
    """Raised by the fake loader: the command reached the cell file (exit 2, the path in its one line)."""


def _commands() -> dict[str, argparse.ArgumentParser]:
    action = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def _required(parser: argparse.ArgumentParser, tmp_path) -> list[str]:
    """Values for the required options (the first option of a required group): enough to parse, not to run."""
    argv: list[str] = []
    groups = [g for g in parser._mutually_exclusive_groups if g.required]
    chosen = {id(g._group_actions[0]) for g in groups}
    in_group = {id(a) for g in groups for a in g._group_actions}
    for action in parser._actions:
        if action.option_strings and (action.required or id(action) in chosen) and action.dest != "help":
            value = (action.choices[0] if action.choices else "3" if action.type in (int, float)
                     else str(tmp_path / f"{action.dest}.none"))
            argv += [action.option_strings[0], str(value)]
        assert not (action.required and id(action) in in_group)
    return argv


#: What a command needs beyond its required options to get as far as the cell file.
EXTRA = {"preview": ["--html", "p.html"], "select": ["--budget", "3"]}

COMMANDS = [name for name in _commands() if name not in NO_CELL]


@pytest.fixture
def fake_cell(monkeypatch):
    """``load_cell`` raising CellLoaded with the path it was given."""
    def load_cell(path=None):
        raise CellLoaded(f"cell file read: {path}")

    monkeypatch.setattr(cell_config, "load_cell", load_cell)
    # and in every module already imported that took the name from the package at its top (``from cell_config
    # import load_cell``); ``cell_config.loader.load_cell`` (init-cell checking the packaged cell) stays real
    for module in list(sys.modules.values()):
        source = getattr(module, "__file__", None) or ""
        if getattr(module, "__name__", "").startswith("app.") and source.endswith(".py") and \
                re.search(r"^from cell_config import [^\n]*\bload_cell\b", Path(source).read_text(), re.M):
            monkeypatch.setattr(module, "load_cell", load_cell)


@pytest.mark.parametrize("command", COMMANDS)
@pytest.mark.parametrize("where", ["before", "after"])
def test_every_command_that_reads_the_cell_takes_cell_before_and_after_its_name(command, where, tmp_path, capsys,
                                                                                 fake_cell):
    cell = str(tmp_path / f"cell_{where}.yaml")
    rest = _required(_commands()[command], tmp_path) + [
        str(tmp_path / a) if a.endswith(".html") else a for a in EXTRA.get(command, [])]
    argv = ["--cell", cell, command, *rest] if where == "before" else [command, "--cell", cell, *rest]
    assert_bad_input(capsys, argv, f"cell file read: {cell}")


def test_the_commands_without_cell_never_read_it(tmp_path, capsys, fake_cell):
    for command in NO_CELL:
        assert "--cell" not in _commands()[command]._option_string_actions
        rest = _required(_commands()[command], tmp_path) + ([str(tmp_path / "new")] if command == "init-cell" else [])
        main([command, *rest])  # fails on the missing session (init-cell: copies the packaged cell), not on --cell
        assert "cell file read" not in capsys.readouterr().err


def test_cell_before_and_after_the_name_must_agree(tmp_path, capsys):
    a, b = str(tmp_path / "a.yaml"), str(tmp_path / "b.yaml")
    assert_bad_input(capsys, ["--cell", a, "fit", "--cell", b, "--robot", "R1", "--train", "t.csv", "--method",
                              "nls1", "--out", str(tmp_path / "m.yaml")], "--cell given twice", a, b)
    assert not (tmp_path / "m.yaml").exists()
