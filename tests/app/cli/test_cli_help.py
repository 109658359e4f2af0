"""Every option of every subcommand has help text, and no help text shows raw docstring markup."""

import argparse
import re

import pytest

from app.cli.commands import build_parser

#: reStructuredText left in a help string: double backticks, any backtick, or a Sphinx role (:class:, :func:).
MARKUP = re.compile(r"`|:[a-z]+:(?=`)|:(class|func|mod|meth|attr|data|obj|exc|ref):")


def _parsers() -> list[tuple[str, argparse.ArgumentParser]]:
    """(name, parser) for the top-level parser and every subcommand's."""
    root = build_parser()
    out = [("cellcal", root)]
    for action in root._actions:
        if isinstance(action, argparse._SubParsersAction):
            out += [(f"cellcal {name}", p) for name, p in action.choices.items()]
    return out


def _subcommand_help() -> list[tuple[str, str | None]]:
    root = build_parser()
    action = next(a for a in root._actions if isinstance(a, argparse._SubParsersAction))
    return [(c.dest, c.help) for c in action._choices_actions]


PARSERS = _parsers()


def test_the_walk_reaches_every_subcommand():
    names = {name for name, _ in PARSERS}
    assert {"cellcal fit", "cellcal demo", "cellcal plan-dual", "cellcal compensate-job"} <= names
    assert len(names) == len(_subcommand_help()) + 1


@pytest.mark.parametrize("name,parser", PARSERS, ids=[n for n, _ in PARSERS])
def test_every_option_has_help_without_markup(name, parser):
    for action in parser._actions:
        if isinstance(action, (argparse._HelpAction, argparse._VersionAction, argparse._SubParsersAction)):
            continue
        flag = "/".join(action.option_strings) or action.dest
        assert action.help and action.help != argparse.SUPPRESS, f"{name} {flag}: no help text"
        assert not MARKUP.search(action.help), f"{name} {flag}: markup in {action.help!r}"
    text = parser.format_help()
    assert not MARKUP.search(text), f"{name} --help shows markup: {MARKUP.search(text).group(0)!r}"


def test_every_subcommand_has_a_one_line_summary_without_markup():
    for name, text in _subcommand_help():
        assert text, f"{name}: no summary in cellcal --help"
        assert not MARKUP.search(text), f"{name}: markup in {text!r}"


def test_the_markup_check_can_fail():
    for text in ("the ``cellcal`` command", "a :class:`Plan`", "see `x`", "a :func: reference"):
        assert MARKUP.search(text), text
    assert not MARKUP.search("R1=FILE,R2=FILE [mm]: a plain line, with a colon: yes")


def _has_default(action: argparse.Action) -> bool:
    """An option whose default a user would otherwise have to guess: not a flag, not None, not an empty list."""
    flags = (argparse._StoreTrueAction, argparse._StoreFalseAction, argparse._HelpAction, argparse._VersionAction,
             argparse._SubParsersAction)
    return (bool(action.option_strings) and not isinstance(action, flags) and action.default is not None
            and action.default != argparse.SUPPRESS and action.default != [])


@pytest.mark.parametrize("name,parser", PARSERS, ids=[n for n, _ in PARSERS])
def test_every_option_with_a_default_states_it_in_help(name, parser):
    """A new user found no defaults in several help texts (plan --noise-mm, compare --methods, fake-motive ...)."""
    formatter = parser._get_formatter()
    for action in filter(_has_default, parser._actions):
        text = formatter._expand_help(action)  # as --help prints it
        d = action.default
        value = f"{d:g}" if isinstance(d, float) else str(d)
        assert re.search(rf"\bdefault:? {re.escape(value)}(?![\w.])", text), \
            f"{name} {action.option_strings[-1]}: default {value} not in {text!r}"


def test_the_default_check_can_fail():
    action = argparse.ArgumentParser().add_argument("--noise-mm", type=float, default=0.05, help="noise [mm]")
    assert _has_default(action)
    assert not re.search(r"\bdefault:? 0\.05(?![\w.])", "noise [mm] (default 0.055)")
