"""The README's and the tutorials' shell blocks run as written, from a fresh copy of the repository; the CLI
reference holds the parser's command table.

The convention the pages follow (docs/index.md, "How these pages are tested"):

- a fenced block of class ``bash`` or ``sh`` runs, every block of a page in order, in one fresh copy per page;
- a fenced block of class ``console`` never runs, and must carry a visible title saying so and why:
  ```` ```console title="not run: needs the real cell" ````;
- a run block may be reduced by the sentence just before it: "The tests run this block with `CMD OPTIONS`, ..."
  (each backticked item appends OPTIONS to the command CMD: argparse keeps the last value).

Lines are split like a shell would (comments dropped, ``\\`` continuations joined, ``$VAR`` expanded from
``VAR=value`` lines). The known commands are ``cellcal`` (or ``.venv/bin/cellcal``), run through ``app.cli.main`` in
this process, and ``. .venv/bin/activate`` (a no-op here: the tests already run in the environment); any other line
fails the test, and so does a command that exits non-zero.

The fresh copy: the files git tracks (with their working-tree contents) plus the pages under test, copied into a
temporary folder, with ``../shared`` beside it linked to the repository's ``../shared``. Not ``git clone`` or
``git archive HEAD``: those hold only committed text, so a page being edited would be tested as it was; and not the
working tree itself, whose outputs of earlier runs (a ``mycell/`` that ``init-cell`` refuses to overwrite, a
``demo_out/``) a fresh checkout does not have. A page that reads ``../shared`` skips when the data are absent.
"""

from __future__ import annotations

import re
import shlex
import shutil
import subprocess
from pathlib import Path

import pytest

from app.cli import main
from app.cli.table import command_table
from tests.conftest import SHARED_DATA, gen_pages

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
PAGES = [README] + sorted((ROOT / "docs" / "tutorials").glob("*.md"))
RUN_CLASSES = ("bash", "sh")
REDUCTION = "The tests run this block with"
FENCE = re.compile(r"^```(\S*)(.*)$")


def command_names() -> set[str]:
    return set(re.findall(r"^\| `([\w-]+)` \|", command_table(), flags=re.M))


def fenced_blocks(text: str) -> list[tuple[str, str, list[str], dict[str, list[str]]]]:
    """(class, attributes, lines with continuations joined, reductions) of every fenced block of a page."""
    out = []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        match = FENCE.match(lines[i])
        if not match:
            i += 1
            continue
        kind, attributes = match.group(1), match.group(2).strip()
        end = next(j for j in range(i + 1, len(lines)) if lines[j].startswith("```"))
        body: list[str] = []
        for line in lines[i + 1:end]:
            if body and body[-1].endswith("\\"):
                body[-1] = body[-1][:-1] + " " + line.strip()
            else:
                body.append(line)
        before = []
        k = i - 1
        while k >= 0 and not lines[k].strip():
            k -= 1
        while k >= 0 and lines[k].strip() and not lines[k].startswith("```"):
            before.insert(0, lines[k])
            k -= 1
        out.append((kind, attributes, body, reductions(" ".join(before))))
        i = end + 1
    return out


def reductions(paragraph: str) -> dict[str, list[str]]:
    """The options the paragraph before a block appends to each command ("The tests run this block with ...")."""
    if REDUCTION not in paragraph:
        return {}
    extra: dict[str, list[str]] = {}
    for item in re.findall(r"`([^`]+)`", paragraph.split(REDUCTION, 1)[1]):
        command, *options = shlex.split(item)
        extra.setdefault(command, []).extend(options)
    return extra


def run_block(block: list[str], variables: dict[str, str], extra: dict[str, list[str]]) -> list[str]:
    """Run every line of ``block``; ``extra`` maps a subcommand to options appended to it. Returns the commands run."""
    names = command_names()
    ran = []
    for line in block:
        words = shlex.split(line, comments=True)
        if not words:
            continue
        if len(words) == 1 and re.fullmatch(r"[A-Za-z_]\w*=.*", words[0]):
            name, value = words[0].split("=", 1)
            variables[name] = value
            continue
        if words in (([".", ".venv/bin/activate"]), ["source", ".venv/bin/activate"]):
            continue
        assert words[0] in ("cellcal", ".venv/bin/cellcal"), f"not a known command: {line}"
        argv = [re.sub(r"\$(\w+)", lambda m: variables[m.group(1)], w) for w in words[1:]]
        command = next((w for w in argv if w in names), None)
        assert command is not None, f"no cellcal command in: {line}"
        argv += extra.get(command, [])
        assert main(argv) == 0, f"command failed: {line}"
        ran.append(command)
    return ran


def fresh_copy(tmp_path: Path, pages: list[Path]) -> Path:
    """The repository as a fresh checkout would be (see the module docstring), with ../shared beside it."""
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout: the files a checkout holds are unknown")
    tracked = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    copy = tmp_path / "cellcal"
    for name in {*tracked.decode().split("\0"), *(str(p.relative_to(ROOT)) for p in pages)} - {""}:
        source = ROOT / name
        if source.is_file():
            (copy / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, copy / name)
    shared = ROOT.parent / "shared"
    if shared.exists():
        (tmp_path / "shared").symlink_to(shared)
    return copy


@pytest.mark.parametrize("page", PAGES, ids=[str(p.relative_to(ROOT)) for p in PAGES])
def test_the_pages_command_blocks_run_in_order_from_a_fresh_copy(page, tmp_path, monkeypatch):
    text = page.read_text(encoding="utf-8")
    runnable = [(body, extra) for kind, _, body, extra in fenced_blocks(text) if kind in RUN_CLASSES]
    if "../shared" in "\n".join("\n".join(body) for body, _ in runnable) and not SHARED_DATA.exists():
        pytest.skip(f"real recordings not found at {SHARED_DATA}")
    for kind, attributes, body, extra in fenced_blocks(text):
        if kind == "console":
            assert re.search(r'title="not run: \S', attributes), \
                f"{page.name}: a console block needs title=\"not run: REASON\": {body[:1]}"
        if extra:
            assert kind in RUN_CLASSES, f"{page.name}: reductions announced before a block that does not run"
    copy = fresh_copy(tmp_path, [page])
    before = set(_files(copy))
    monkeypatch.chdir(copy)
    variables: dict[str, str] = {}
    for body, extra in runnable:
        ran = run_block(body, variables, extra)
        for command in extra:
            assert command in ran, f"{page.name}: a reduction for {command}, which the block does not run"
    written = sorted(set(_files(copy)) - before)
    assert not (left := not_ignored(written)), f"{page.name} leaves files git does not ignore: {left[:5]}"


def _files(root: Path) -> list[str]:
    """Every file under ``root``, relative to it (POSIX)."""
    return [p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file() or p.is_symlink()]


def not_ignored(paths: list[str]) -> list[str]:
    """Those of ``paths`` (relative to the repository root) that the repository's .gitignore does not ignore: what a
    page's commands would leave in ``git status`` (the README's tour wrote r1_plan.json, s_r1/ ... into the root)."""
    if not paths:
        return []
    done = subprocess.run(["git", "check-ignore", "--no-index", "--stdin", "-z"], cwd=ROOT, input="\0".join(paths),
                          capture_output=True, text=True)
    assert done.returncode in (0, 1), done.stderr
    ignored = set(done.stdout.split("\0"))
    return [p for p in paths if p not in ignored]


def test_the_ignore_check_tells_an_output_under_tutorial_out_from_one_in_the_root():
    assert not_ignored(["tutorial_out/readme/r1_plan.json", "r1_plan.json", "demo_out/report.html"]) == ["r1_plan.json"]


def test_the_block_reader_joins_continuations_reads_reductions_and_the_runner_refuses_other_commands():
    text = ("The tests run this block with `fit --method nls1`, `plan --budget 49 --validation 6`.\n\n"
            "```bash\nD=x\ncellcal fit --a \\\n    --b $D  # note\n```\n\n"
            "```console title=\"not run: needs the real cell\"\npython other.py\n```\n")
    assert fenced_blocks(text) == [
        ("bash", "", ["D=x", "cellcal fit --a  --b $D  # note"],
         {"fit": ["--method", "nls1"], "plan": ["--budget", "49", "--validation", "6"]}),
        ("console", 'title="not run: needs the real cell"', ["python other.py"], {})]
    with pytest.raises(AssertionError, match="not a known command"):
        run_block(["python other.py"], {}, {})
    with pytest.raises(AssertionError, match="no cellcal command"):
        run_block(["cellcal --version-of-nothing"], {}, {})


def test_an_unmarked_failing_block_fails_and_a_console_block_without_its_reason_is_refused(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(AssertionError, match="command failed"):
        run_block(["cellcal evaluate --model missing.yaml --test missing.csv"], {}, {})
    page = tmp_path / "page.md"
    page.write_text("```console\ncellcal --cell cell.yaml register --robot R1\n```\n")
    with pytest.raises(AssertionError, match="not run: REASON"):
        test_the_pages_command_blocks_run_in_order_from_a_fresh_copy(page, tmp_path, monkeypatch)


def test_the_cli_reference_holds_the_parsers_command_table_and_every_commands_help():
    page = gen_pages().cli_page()
    assert command_table() in page
    for name in command_names():
        assert f"## `{name}`\n\n```text\nusage: cellcal {name} " in page, name
