"""``-`` as an output (issue 34): ``cellcal export-urdf --out -`` wrote a file literally named ``-``. Every command
writes its outputs to files (several at once, with a summary on stdout), so ``-`` is refused, for every option of
every command that names something written, in one line before any work, and nothing named ``-`` appears."""

from __future__ import annotations

import argparse
import os

import pytest

from app.cli.commands import build_parser, main
from app.cli.common import SESSION_WRITERS
from app.cli.table import OUTPUT_OPTIONS, _subcommands

#: What the docs' command table lists as written, and --json (the machine-readable summary file).
WRITTEN = (*OUTPUT_OPTIONS, "--json")


def _flag(action: argparse.Action) -> str:
    return next(s for s in action.option_strings if s.startswith("--"))


def _cases() -> list[tuple[str, str, list[str]]]:
    """(command, output option, argv with every other required option filled) for every option written to."""
    cases = []
    for name, parser, _ in _subcommands(build_parser()):
        options = [a for a in parser._actions if a.option_strings]
        for out in options:
            if _flag(out) not in WRITTEN and not (_flag(out) == "--session" and name in SESSION_WRITERS):
                continue
            argv = [name] + ["absent_input" for a in parser._actions if not a.option_strings]  # positionals
            group_firsts = [g._group_actions[0] for g in parser._mutually_exclusive_groups if g.required]
            for a in options:
                if (a.required or a in group_firsts) and a is not out:
                    value = str(a.choices[0]) if a.choices else "1" if a.type in (int, float) else "absent_input"
                    argv += [_flag(a), value]
            cases.append((name, _flag(out), argv + [_flag(out), "-"]))
    return cases


CASES = _cases()


def test_the_family_holds_the_single_file_outputs_named_in_the_issue():
    named = {(c, o) for c, o, _ in CASES}
    assert {("export-urdf", "--out"), ("fit", "--out"), ("plan", "--out"), ("fit", "--json")} <= named
    assert len(CASES) > 20


@pytest.mark.parametrize(("command", "option", "argv"), CASES, ids=[f"{c} {o}" for c, o, _ in CASES])
def test_dash_as_an_output_is_refused_in_one_line_and_nothing_is_written(command, option, argv, tmp_path, capsys,
                                                                        monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{option} -" in err[0] and "standard output" in err[0], (argv, err)
    assert os.listdir(tmp_path) == [], (argv, os.listdir(tmp_path))
