#!/usr/bin/env python3
"""Step 3 of PLAN32: lift function-local imports to module level, except the heavy optional ones.

    python plan32/lift.py --repo . [--dry-run] [--only calibration,app]

For every module of the product (calibration, app, drivers, cell_config), every ``import``/``from .. import``
statement inside a ``def`` (not inside a ``try`` — an optional-dependency guard — and not of a HEAVY package)
is removed from the function and added once after the module's last top-level import. Skipped and reported:
a name the module already binds at top level to something else; an import inside ``try``; a statement sharing
its line. Afterwards run ``plan32/imports.py`` + ``plan32/analyse.py summary``: a lifted import that closes a
circle shows up as an SCC and must wait for (or cause) a seam.
"""
from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

PRODUCT = ("calibration", "app", "drivers", "cell_config")
# only imports of the product's own modules are lifted (the circles hid behind them); stdlib and third-party
# imports stay where they are, so a lift adds no import time of its own (tqdm, importlib.metadata, ...)
PROJECT_ONLY = True
# kept local (CONVENTIONS: heavy or optional, so `cellcal --help` stays fast); ruff TID253 enforces it
HEAVY = {"casadi", "meshcat", "zenoh", "pinocchio", "sklearn", "matplotlib", "jinja2", "tornado", "umsgpack", "can",
         "scipy", "threadpoolctl", "pin", "cmeel", "coal", "IPython"}


def top_name(node: ast.Import | ast.ImportFrom) -> str:
    mod = node.module if isinstance(node, ast.ImportFrom) else node.names[0].name
    return (mod or "").split(".")[0]


def bound(node: ast.Import | ast.ImportFrom) -> dict[str, str]:
    """Names a statement binds -> what they are (for collision checks)."""
    out = {}
    for a in node.names:
        if isinstance(node, ast.ImportFrom):
            out[a.asname or a.name] = f"{node.module}.{a.name}"
        else:
            out[a.asname or a.name.split(".")[0]] = a.name if a.asname else a.name.split(".")[0]
    return out


def lift(path: Path, rel: str, report: list[str]) -> str | None:
    text = path.read_text()
    tree = ast.parse(text)
    lines = text.splitlines(keepends=True)
    top_bind: dict[str, str] = {}
    for node in tree.body:
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            top_bind.update(bound(node))
        elif isinstance(node, (ast.FunctionDef, ast.ClassDef, ast.AsyncFunctionDef)):
            top_bind[node.name] = f"<def {node.name}>"
        elif isinstance(node, ast.Assign):
            for t in node.targets:
                for n in ast.walk(t):
                    if isinstance(n, ast.Name):
                        top_bind[n.id] = f"<assign {n.id}>"
    in_try: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Try):
            for n in ast.walk(node):
                in_try.add(id(n))
    remove: list[tuple[int, int]] = []
    add: list[str] = []
    seen: set[str] = set()
    for fn in ast.walk(tree):
        if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        for node in ast.walk(fn):
            if not isinstance(node, (ast.Import, ast.ImportFrom)) or getattr(node, "level", 0):
                continue
            if top_name(node) in HEAVY or top_name(node) == "__future__" or (PROJECT_ONLY and top_name(node) not in PRODUCT):
                continue
            if id(node) in in_try:
                report.append(f"{rel}:{node.lineno}: inside try (optional dependency?): left local")
                continue
            clash = {n: w for n, w in bound(node).items() if n in top_bind and top_bind[n] != w}
            if clash:
                report.append(f"{rel}:{node.lineno}: would rebind {clash} at module level: left local")
                continue
            first, last = node.lineno - 1, node.end_lineno - 1
            if lines[first][: node.col_offset].strip() or lines[last][node.end_col_offset:].strip().split("#")[0]:
                report.append(f"{rel}:{node.lineno}: shares its line: left local")
                continue
            stmt = ast.unparse(node)
            remove.append((first, last + 1))
            if stmt not in seen:
                seen.add(stmt)
                add.append(stmt + "\n")
                top_bind.update(bound(node))
    if not remove:
        return None
    at = max((n.end_lineno for n in tree.body if isinstance(n, (ast.Import, ast.ImportFrom))), default=0)
    if at == 0 and tree.body and isinstance(tree.body[0], ast.Expr):   # after the docstring
        at = tree.body[0].end_lineno
    edits = [(first, end, [] if not _only_stmt(tree, first) else
              [lines[first][: len(lines[first]) - len(lines[first].lstrip())] + "pass  # TODO(PLAN32) lifted import\n"])
             for first, end in set(remove)]
    edits.append((at, at, add))
    for first, end, new in sorted(edits, key=lambda e: (e[0], e[1]), reverse=True):   # bottom up: indices hold
        lines[first:end] = new
    return "".join(lines)


def _only_stmt(tree: ast.Module, line0: int) -> bool:
    for fn in ast.walk(tree):
        if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            body = [s for s in fn.body if not (isinstance(s, ast.Expr) and isinstance(getattr(s, "value", None),
                                                                                      ast.Constant))]
            if body and all(isinstance(s, (ast.Import, ast.ImportFrom)) for s in body) \
                    and body[0].lineno - 1 == line0:
                return True
    return False


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repo", default=".")
    ap.add_argument("--dry-run", action="store_true")
    ap.add_argument("--only", default=",".join(PRODUCT))
    a = ap.parse_args(argv)
    repo = Path(a.repo).resolve()
    report: list[str] = []
    n = 0
    for root in a.only.split(","):
        for p in sorted((repo / root).rglob("*.py")):
            if "__pycache__" in p.parts:
                continue
            rel = str(p.relative_to(repo))
            new = lift(p, rel, report)
            if new is not None:
                n += 1
                print(f"lift {rel}")
                if not a.dry_run:
                    p.write_text(new)
    print(f"{n} modules changed; {len(report)} imports left local:")
    print("\n".join(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
