"""The table of commands, generated from the parser: ``python -m app.cli.table`` prints it.

Per subcommand: its required options, the options it writes to, whether it takes ``--json``, and its summary.
The docs' CLI reference (docs/gen_pages.py) holds it, and a test checks that it does.
"""

from __future__ import annotations

import argparse

from app.cli.common import SESSION_WRITERS

#: Options naming something a command writes (files or folders), in the order the parser declares them.
OUTPUT_OPTIONS = ("--out", "--report", "--html", "--model-dir", "--xacro", "--jbi")

HEADER = "| command | required inputs | writes | `--json` | what |\n|---|---|---|---|---|"


def _subcommands(parser: argparse.ArgumentParser) -> list[tuple[str, argparse.ArgumentParser, str]]:
    """(name, parser, one-line summary) of every subcommand, in the order of ``cellcal --help``."""
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    summaries = {c.dest: c.help or "" for c in action._choices_actions}
    return [(name, p, summaries[name]) for name, p in action.choices.items()]


def _row(name: str, parser: argparse.ArgumentParser, summary: str) -> str:
    options = [a for a in parser._actions if a.option_strings]

    def flag(a: argparse.Action) -> str:  # the (first) long name
        return next(s for s in a.option_strings if s.startswith("--"))

    required = " ".join(f"`{flag(a)}`" for a in options if a.required)
    writes = [flag(a) for a in options
              if flag(a) in OUTPUT_OPTIONS or (flag(a) == "--session" and name in SESSION_WRITERS)]
    has_json = any("--json" in a.option_strings for a in options)
    return (f"| `{name}` | {required or '–'} | {', '.join(f'`{w}`' for w in writes) or '–'} | "
            f"{'yes' if has_json else 'no'} | {summary} |")


def command_table(parser: argparse.ArgumentParser | None = None) -> str:
    """The Markdown table of every ``cellcal`` subcommand (header included)."""
    if parser is None:
        from app.cli.commands import build_parser

        parser = build_parser()
    return "\n".join([HEADER] + [_row(*entry) for entry in _subcommands(parser)])


if __name__ == "__main__":
    print(command_table())
