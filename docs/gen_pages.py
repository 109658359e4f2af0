"""Pages generated at build time (mkdocs-gen-files): the CLI reference from the parser, the API pages from the packages,
the drawing of the imports from the code (grimp, the engine import-linter checks the contracts with).

The parser is imported on one line only (``build_parser`` below): when the CLI module moves, change that line.
The API pages are found by walking the package folders, so a module that moves takes its page along with it.
``python docs/gen_pages.py`` prints the CLI reference without mkdocs (the tests read it through :func:`cli_page`).
"""

from __future__ import annotations

import argparse
import os
from collections import Counter
from pathlib import Path

import grimp

from app.cli.commands import build_parser  # the one import of the parser in the docs
from app.cli.table import command_table

ROOT = Path(__file__).resolve().parents[1]

#: The packages whose modules get an API page, in the order of the site's API section.
PACKAGES = ("calibration", "cell_config", "drivers", "app")

#: Help text is wrapped at this width whatever the terminal, so the page is the same on every machine.
HELP_COLUMNS = "100"


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def cli_page() -> str:
    """The CLI reference page (Markdown): the command table, then ``cellcal --help`` and each command's help."""
    saved = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = HELP_COLUMNS
    try:
        parser = build_parser()
        parts = [
            "# CLI reference",
            "",
            "Generated from the parser when the site is built: every option below is the one `cellcal` accepts.",
            "Every command that reads the cell takes `--cell CELL` (default: the packaged cell) before or after its",
            "name; `--json FILE` writes the figures a command prints as JSON. Bad input exits 2 with one line on",
            "stderr and writes nothing; Ctrl-C exits 130. Outputs are files: `-` is refused as an output (it is",
            "not standard output here; every command may write several files and prints its summary on stdout).",
            "",
            "## Commands",
            "",
            command_table(parser),
            "",
            "## `cellcal`",
            "",
            "```text",
            parser.format_help().rstrip(),
            "```",
        ]
        for name, sub in _subparsers(parser).items():
            parts += ["", f"## `{name}`", "", "```text", sub.format_help().rstrip(), "```"]
        return "\n".join(parts) + "\n"
    finally:
        if saved is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = saved


def api_modules() -> list[str]:
    """Dotted names of every module of the packages (``__init__`` as the package), found on disk, sorted."""
    names = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__main__":
                continue
            if parts[-1] == "__init__":
                parts = parts[:-1]
            names.append(".".join(parts))
    return sorted(names)


def api_page(module: str) -> str:
    """A module's API page: its docstring (the modules' docstrings say what each holds and why).

    The members are left out: rendering every function and class of the 180 modules costs ~9 s of CPU per build
    against ~4 s for the whole site without them, and ``make test`` builds the site every time.
    """
    return f"# `{module}`\n\n::: {module}\n    options:\n      members: false\n"


def api_path(module: str) -> str:
    """A module's page under api/: a package's is its folder's index.md, so its section opens on it."""
    parts = module.split(".")
    if ROOT.joinpath(*parts).is_dir():
        return Path(*parts, "index.md").as_posix()
    return Path(*parts).with_suffix(".md").as_posix()


def folder_edges() -> Counter[tuple[str, str]]:
    """Imports between the product's folders, counted module pair by module pair (every import, function-local too).

    A folder is a top package's direct child (``calibration.frames``, ``app.cli``; a loose module counts as its own
    folder) or, across top packages, the top package itself (``app -> calibration``).
    """
    graph = grimp.build_graph(*PACKAGES, include_external_packages=False, cache_dir=None)
    edges: Counter[tuple[str, str]] = Counter()
    for importer in graph.modules:
        for imported in graph.find_modules_directly_imported_by(importer):
            a, b = importer.split("."), imported.split(".")
            if a[0] != b[0]:
                edges[(a[0], b[0])] += 1
            elif len(a) > 1 and len(b) > 1 and a[1] != b[1]:
                edges[(".".join(a[:2]), ".".join(b[:2]))] += 1
    return edges


def _mermaid(edges: dict[tuple[str, str], int]) -> list[str]:
    lines = ["```mermaid", "flowchart TD"]
    nodes = sorted({n for edge in edges for n in edge})
    lines += [f'    {n.replace(".", "_")}["{n.split(".")[-1]}"]' for n in nodes]
    lines += [f"    {a.replace('.', '_')} -->|{k}| {b.replace('.', '_')}" for (a, b), k in sorted(edges.items())]
    return [*lines, "```"]


def imports_page() -> str:
    """The import drawing (Markdown with Mermaid): the four top packages, then the folders inside each."""
    edges = folder_edges()
    parts = ["# Import graph", "",
             "Drawn from the code when the site is built, with grimp (the engine `lint-imports` checks the",
             "contracts in `pyproject.toml` with); every import counts, function-local ones too. An arrow is",
             "\"imports\", its number the module pairs behind it. There is no circle: `make test` fails on one.",
             "", "## The product's layers", ""]
    parts += _mermaid({e: k for e, k in edges.items() if "." not in e[0]})
    for package in PACKAGES:
        inside = {e: k for e, k in edges.items() if e[0].startswith(package + ".")}
        if inside:
            parts += ["", f"## Inside `{package}/`", "", *_mermaid(inside)]
    return "\n".join(parts) + "\n"


def write_pages() -> None:
    import mkdocs_gen_files

    with mkdocs_gen_files.open("reference/cli.md", "w") as page:
        page.write(cli_page())
    for module in api_modules():
        with mkdocs_gen_files.open(Path("api", api_path(module)), "w") as page:
            page.write(api_page(module))
    with mkdocs_gen_files.open("reference/imports.md", "w") as page:
        page.write(imports_page())
    with mkdocs_gen_files.open("api/index.md", "w") as page:
        page.write("# API\n\nThe Python modules, from their docstrings. The command line (`cellcal`) is the supported "
                   "interface; these pages are for readers of the code.\n\n"
                   + "\n".join(f"* [`{m}`]({api_path(m)})" for m in api_modules()) + "\n")


if __name__ == "__main__":
    print(cli_page(), end="")
elif __name__ == "<run_path>":  # run by mkdocs-gen-files (runpy.run_path) during the build
    write_pages()
