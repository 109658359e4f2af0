"""The README's command table is the parser's, and its shell blocks run as written (from a temporary folder).

A block is a run of 4-space-indented lines. Lines are split like a shell would (comments dropped, ``\\``
continuations joined, ``$VAR`` expanded from ``VAR=value`` lines); every command is ``cellcal`` (or
``.venv/bin/cellcal``) and runs through :func:`app.cli.commands.main`. Slow blocks run with the reductions the
README itself announces next to them (appended options: argparse keeps the last value).
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from app.cli.commands import main
from app.cli.table import command_table
from tests.conftest import SHARED_DATA, needs_shared_data

README = Path(__file__).resolve().parents[1] / "README.md"


def blocks(text: str) -> list[list[str]]:
    """The README's indented code blocks, each as its lines with continuations joined."""
    out: list[list[str]] = []
    current: list[str] = []
    for line in text.splitlines() + [""]:
        if line.startswith("    ") and not line.lstrip().startswith("|"):
            current.append(line[4:])
        else:
            if current:
                out.append(current)
            current = []
    joined = []
    for block in out:
        lines: list[str] = []
        for line in block:
            if lines and lines[-1].endswith("\\"):
                lines[-1] = lines[-1][:-1] + " " + line.strip()
            else:
                lines.append(line)
        joined.append(lines)
    return joined


def block_with(fragment: str) -> list[str]:
    found = [b for b in blocks(README.read_text()) if any(fragment in line for line in b)]
    assert len(found) == 1, f"{len(found)} README blocks contain {fragment!r}"
    return found[0]


def run_block(block: list[str], variables: dict[str, str], extra: dict[str, list[str]]) -> list[str]:
    """Run every command of ``block``; ``extra`` maps a subcommand to options appended to it. Returns them."""
    ran = []
    for line in block:
        words = shlex.split(line, comments=True)
        if not words:
            continue
        if len(words) == 1 and re.fullmatch(r"[A-Za-z_]\w*=.*", words[0]):
            name, value = words[0].split("=", 1)
            variables.setdefault(name, value)
            continue
        assert words[0] in ("cellcal", ".venv/bin/cellcal"), f"README line is not a cellcal command: {line}"
        argv = [re.sub(r"\$(\w+)", lambda m: variables[m.group(1)], w) for w in words[1:]]
        command = next(w for w in argv if not w.startswith("-"))
        added = extra.get(command, [])
        announced = " ".join(w for w in added if w != "--no-progress")
        assert announced in README.read_text(), f"the README does not announce {announced!r} for {command}"
        argv += added
        assert main(argv) == 0, f"README command failed: {line}"
        ran.append(command)
    return ran


def test_the_readme_command_table_is_the_parsers():
    assert command_table() in README.read_text(), "regenerate it: python -m app.cli.table"


def test_the_block_reader_joins_continuations_and_the_runner_refuses_other_commands():
    text = "intro\n\n    D=x\n    cellcal fit --a \\\n        --b $D  # note\n\nafter\n    python other.py\n"
    assert blocks(text) == [["D=x", "cellcal fit --a  --b $D  # note"], ["python other.py"]]
    with pytest.raises(AssertionError, match="not a cellcal command"):
        run_block(["python other.py"], {}, {})


@needs_shared_data()
def test_the_real_data_block_runs_as_written(tmp_path, monkeypatch):
    block = block_with("D=../shared/data/welding_motoman")
    monkeypatch.chdir(tmp_path)
    ran = run_block(block, {"D": str(SHARED_DATA)}, {"compare": ["--methods", "nominal,base,nls1,pi"]})
    assert ran == ["compare"]
    assert (tmp_path / "cmp.json").stat().st_size > 0 and (tmp_path / "report" / "report.md").exists()


def test_the_step_by_step_block_runs_as_written_on_a_small_optimal_design(tmp_path, monkeypatch):
    block = block_with("cellcal plan --robot R1 --out r1_plan.json")
    monkeypatch.chdir(tmp_path)
    ran = run_block(block, {}, {"plan": ["--budget", "49", "--validation", "6"],
                                "collect": ["--time-scale", "200", "--no-progress"],
                                "compare": ["--methods", "nominal,base,nls1,cpa"],
                                "recalibrate": ["--method", "nls1", "--validation", "3", "--time-scale", "200",
                                                "--no-progress"]})
    assert ran == ["plan", "collect", "export", "export", "export", "compare", "recalibrate"]
    for name in ("r1_train.csv", "r1_cpa.csv", "r1_test.csv", "rep/report.md", "d.json",
                 "models_r1/current.yaml"):
        assert (tmp_path / name).exists(), name
