#!/usr/bin/env python3
"""The mechanical part of issue 32's restructure: move modules, split listed top-level definitions, rewrite
every import and dotted/path reference. NOT run on /work/main: run it in a clean work tree of a branch.

    python plan32/move.py --repo . --dry-run        # print what would change, touch nothing
    python plan32/move.py --repo .                  # git mv + rewrites
    python plan32/move.py --repo . --split          # also cut the top-level definitions of SPLITS
    python plan32/move.py --repo . --no-git         # plain renames (a copy that is not a git work tree)
    python plan32/move.py --repo . --rewrite-only FILE...   # after the move: rewrite files written for the old tree

``--rewrite-only`` is for files other branches add or change in the old layout and that are merged after the move:
it reads ``rewrite_map.json`` (written beside this script by the move itself: every module move, every name that
changed module, every moved path), ``git mv``s a FILE given by its old path to its new one (a row of table.tsv),
then rewrites its imports, dotted names, path strings and ``parents[N]`` depth exactly as the move did, and runs
``ruff --fix`` (import order, unused imports) on it. A file at an old path with no row is reported, not moved.

Inputs: ``table.tsv`` beside this file (old path, new path, note; new "-" = delete, old "+new" = created) and
the SPLITS / SHIM_SYMBOLS / STRING_OVERRIDES tables below. Outputs: the changed tree and ``move-report.txt``
in the repo root listing what it could not do (to be done by hand; PLAN32.md section 5 lists the known ones).

Order: 1. moves (git mv), 2. splits (optional), 3. deletes (shims), 4. import rewrite (ast spans),
5. dotted-name pass (code, strings, comments) and path pass (README, Makefile, pyproject, .ci, path literals),
6. ``Path(__file__).parents[N]`` depth fix, 7. new package ``__init__.py`` files, 8. ``ruff --fix`` I/F401.
It refuses to run twice (it checks that ``calibration/methods.py`` still exists).
"""
from __future__ import annotations

import argparse
import ast
import os
import re
import subprocess
import sys
from collections import OrderedDict
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOTS = ("calibration", "app", "drivers", "cell_config", "scripts", "tests")
TEXT_FILES = ("README.md", "Makefile", "pyproject.toml", ".ci/run", "CONVENTIONS.md")

# --- names that change module inside a file (split) -------------------------------------------------------
# old module -> [(new module or None for "delete here, defined elsewhere", [top-level names])]. Module-level
# constants the moved code reads move with it automatically; a function/class it reads that stays behind is
# reported (the import back would be a circle).
SPLITS: dict[str, list[tuple[str | None, list[str]]]] = {
    "calibration.methods": [
        ("calibration.method_names", ["CONSTANT_METHODS", "CDC_INTERPOLATORS", "CDC_REFERENCES", "PAPER_CDC_METHODS",
                                      "PI_CDC_METHODS", "CDC_METHODS", "PHYSICS_METHODS", "NEURAL_METHODS",
                                      "REFERENCE_FITS", "METHODS", "cdc_method"]),
        ("calibration.methods.options", ["FitOptions"]),
        ("calibration.methods.pi", ["base_free_prior"]),
    ],
    "calibration.models.base": [
        ("calibration.physics.layout", ["Block"]),
        ("calibration.kinematics.poe", ["poe_to_dict", "poe_from_dict"]),
        ("calibration.models.registry", ["MODEL_KIND_MODULES", "model_class"]),
        ("calibration.models.files", ["_plain", "save_model", "_read_model_file", "load_model"]),
        # by hand: KinematicModel._registry becomes registry.KINDS (filled by __init_subclass__), so the
        # registry imports nothing of models; SCHEMA/READABLE_SCHEMAS stay in base (to_dict/from_dict use them).
    ],
    "calibration.physics_informed": [
        ("calibration.physics.layout", ["DEFLECTION_TERMS", "DEFLECTION_AXES", "TOOL_NAMES", "BLOCKS", "_TAIL_SIZES",
                                        "REGISTRATION_PARTS", "check_registration_parts", "EZ", "block_slice",
                                        "deflection_terms", "deflection_basis"]),
        (None, ["__getattr__"]),
    ],
    "calibration.physics.base": [
        ("calibration.physics.context", ["Context", "FittedSpan", "check_q", "context_array", "context_dirs",
                                         "context_qd", "check_joints"]),
        ("calibration.physics.extended", ["ExtendedEffect"]),
    ],
    "calibration.physics.compliance": [
        ("calibration.physics.layout", ["COMPLIANCE_NAMES"]),
        ("calibration.physics.extended", ["MassFreeCompliance"]),
    ],
    "calibration.physics": [(None, ["__getattr__"])],
    "calibration.design": [("calibration.frames.rebase_design", ["REBASE_OFFSETS", "rebase_candidates"])],
    "calibration.frames": [("calibration.data.recording", ["take_out", "put_in"])],
    "calibration.registration": [("calibration.kinematics.so3", ["make_T"])],
    "calibration.models.rebased": [(None, ["make_T"])],  # identical to registration's, now in so3
    "calibration.robust": [
        ("calibration.methods.workspace", ["WORKSPACE_RATIO_LIMIT", "RANGE_EXCESS_LIMIT", "probe_grid",
                                           "range_excess", "workspace_probes", "workspace_ratio"]),
        ("calibration.workers", ["default_workers"]),
    ],
    "calibration.diagnosis.fits": [("calibration.workers", ["usable_workers"])],
    "calibration.daydiff": [
        # DaysProblem.solve() builds a DaysResult today: by hand, solve() returns (x, own) and compare_days
        # calls DaysResult.build(problem, x, own), so days_problem never imports daydiff.
        ("calibration.frames.day_tests", ["Test", "Quantity", "DayDiff", "pose_overlap"]),
        ("calibration.frames.days_problem", ["Named", "named_changes", "_Day", "DaysProblem", "_copy", "_sigmas",
                                             "identified", "share_in", "sparsest", "common", "covariance"]),
    ],
    "app.analysis.compare": [("calibration.evaluation.comparison", ["Comparison"])],
    "app.analysis.fitting": [("calibration.frames.policy", ["refuse_repeated", "refuse_unexplained",
                                                            "refuse_another_arms"])],
    "app.analysis.report": [
        ("app.reports.acceptance", ["Tolerance", "Acceptance", "acceptance", "acceptance_from_max",
                                    "IsoTable", "iso_table", "iso_unavailable"]),
        ("app.reports.sections", ["PAPER_COLUMN", "acceptance_markdown", "shows_paper",
                                  "comparison_table", "comparison_rows", "analysis_tables", "error_plots",
                                  "comparison_section", "write_report", "evaluation_section",
                                  "write_evaluation_report", "write_demo_report"]),
    ],
    "app.analysis.diagnose": [("app.reports.diagnosis", ["markdown", "write_report", "_days_tables", "_pyplot"])],
    "app.cell.plan_file": [("app.collection.plans.schema", ["PLAN_SCHEMA", "PlanKind", "PLAN_KINDS", "_LAYOUTS",
                                                            "plan_kind", "json_numbers"])],
    "app.cell.planning": [("app.collection.plans.collection", ["VALIDATION_CLUSTER", "Target", "Plan"])],
    "app.demo.run": [("app.collection.collect", ["DEMO_COLLECT", "collect_arm"])],
    "app.cli.commands": [("app.cli.analysis", ["cmd_fit", "cmd_predict", "_counts_explained", "_warn_extrapolation",
                                               "_model_arg", "cmd_evaluate", "_test_frame_check",
                                               "EXTRAPOLATED_SHARE", "_extrapolation_caveat", "REBASE_MIN_CLUSTERS",
                                               "cmd_rebase", "_check_rebase_tolerance", "cmd_export_urdf",
                                               "cmd_compare", "cmd_diagnose", "_add_fit_inputs"])],
    "app.jobs.cli": [("app.jobs.compensate", ["load_job_models"])],
}

# Constants that stay in their module even when only moved code reads them (the moved code imports them).
KEEP: dict[str, set[str]] = {
    "calibration.models.base": {"SCHEMA", "READABLE_SCHEMAS", "log"},
    "calibration.robust": {"N_FOLDS", "NEURAL_EVALUATED_FOLDS"},
}

# Old import paths of shims and second paths (§2.4): (old module, name or "*") -> defining module (new tree).
SHIM_SYMBOLS: dict[tuple[str, str], str] = {
    ("calibration.cpa", "*"): "calibration.identification.cpa",
    ("calibration.observability", "*"): "calibration.identification.observability",
    ("calibration.physics.model", "*"): "calibration.models.physics",
    ("calibration.physics", "PhysicsModel"): "calibration.models.physics",
    ("calibration.physics_informed", "PhysicsInformedModel"): "calibration.models.pi",
    ("calibration.diagnosis.model", "DiagnosedModel"): "calibration.models.diagnosed",
    ("calibration.diagnosis", "DiagnosedModel"): "calibration.models.diagnosed",
    ("calibration.diagnosis.extended", "ExtendedEffect"): "calibration.physics.extended",
    ("calibration.diagnosis.extended", "MassFreeCompliance"): "calibration.physics.extended",
    ("calibration.diagnosis", "ExtendedEffect"): "calibration.physics.extended",
    ("calibration.diagnosis", "MassFreeCompliance"): "calibration.physics.extended",
    ("calibration.physics", "ExtendedEffect"): "calibration.physics.extended",
    ("calibration.models.rebased", "make_T"): "calibration.kinematics.so3",
    ("calibration.models", "poe_from_dict"): "calibration.kinematics.poe",
    ("calibration.models", "poe_to_dict"): "calibration.kinematics.poe",
    ("calibration.models", "Block"): "calibration.physics.layout",
    ("calibration.models", "MODEL_KIND_MODULES"): "calibration.models.registry",
}

# Strings that name a package for a loader, not a module to import.
STRING_OVERRIDES = {"app.analysis": "app.reports"}


# --- the table ----------------------------------------------------------------------------------------------
def mod_of(path: str) -> str:
    p = path[:-3] if path.endswith(".py") else path
    parts = p.split("/")
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def load_table() -> tuple[list[tuple[str, str, str]], dict[str, str | None], dict[str, str]]:
    rows = []
    for line in (HERE / "table.tsv").read_text().splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        old, new, *note = line.split("\t")
        rows.append((old, new, note[0] if note else ""))
    moves: dict[str, str | None] = {}   # old module -> new module (None: deleted)
    paths: dict[str, str] = {}          # old file path -> new file path (moved files and folders)
    for old, new, _ in rows:
        if old == "+new" or not old.endswith(".py"):
            if old.endswith(".j2") and new != "-":
                paths[str(Path(old).parent)] = str(Path(new).parent)
            continue
        if new == "-":
            moves[mod_of(old)] = None
        elif new != old:
            moves[mod_of(old)] = mod_of(new)
            paths[old] = new
    # folders that disappear or move as a whole (app/analysis -> split, app/cell -> collection, ...)
    moves.setdefault("app.analysis", None)
    moves.setdefault("app.demo", None)
    return rows, moves, paths


def symbol_table(moves: dict[str, str | None]) -> dict[tuple[str, str], str]:
    sym = dict(SHIM_SYMBOLS)
    for old_mod, parts in SPLITS.items():
        for target, names in parts:
            for n in names:
                if target is not None:
                    sym[(old_mod, n)] = target
    return sym


def second_paths(repo: Path) -> dict[tuple[str, str], str]:
    """Names imported from a (non-package) module that only re-imports them: (module, name) -> the module
    that defines the name (old tree). Every importer is pointed at the definition (one import path each)."""
    mods: dict[str, Path] = {}
    for r in ROOTS:
        for p in (repo / r).rglob("*.py"):
            if "__pycache__" not in p.parts:
                mods[mod_of(str(p.relative_to(repo)))] = p
    defs: dict[str, set[str]] = {}
    imported: dict[str, dict[str, tuple[str, str]]] = {}
    for m, p in mods.items():
        tree = ast.parse(p.read_text())
        defs[m] = {n for node in tree.body for n in node_names(node)}
        imported[m] = {(a.asname or a.name): (node.module, a.name) for node in tree.body
                       if isinstance(node, ast.ImportFrom) and node.module for a in node.names}
    out: dict[tuple[str, str], str] = {}
    for m, p in mods.items():
        if p.name == "__init__.py":
            continue
        for name, (src, orig) in imported[m].items():
            if name in defs[m] or src not in mods or name != orig:
                continue
            real = src
            while real in imported and orig in imported[real] and orig not in defs.get(real, set()) \
                    and not str(mods.get(real, "")).endswith("__init__.py"):
                real = imported[real][orig][0]
            out[(m, name)] = real
    return out


# --- helpers -------------------------------------------------------------------------------------------------
class Report:
    def __init__(self) -> None:
        self.lines: list[str] = []

    def __call__(self, msg: str) -> None:
        self.lines.append(msg)
        print(msg)


def sh(repo: Path, *cmd: str, dry: bool) -> None:
    print("$", " ".join(cmd))
    if not dry:
        subprocess.run(cmd, cwd=repo, check=True)


def py_files(repo: Path) -> list[Path]:
    out = []
    for r in ROOTS:
        for p in (repo / r).rglob("*.py"):
            if "__pycache__" not in p.parts:
                out.append(p)
    return sorted(out)


# --- 1. moves ------------------------------------------------------------------------------------------------
def do_moves(repo: Path, rows, git: bool, dry: bool, rep: Report) -> None:
    for old, new, _ in rows:
        if old == "+new" or new == "-" or old == new:
            continue
        src, dst = repo / old, repo / new
        if not src.exists():
            rep(f"MISSING {old} (table row skipped)")
            continue
        if not dry:
            dst.parent.mkdir(parents=True, exist_ok=True)
        if git:
            sh(repo, "git", "mv", old, new, dry=dry)
        else:
            print(f"mv {old} {new}")
            if not dry:
                os.replace(src, dst)


def do_deletes(repo: Path, rows, git: bool, dry: bool, rep: Report) -> None:
    for old, new, note in rows:
        if new != "-" or old == "+new":
            continue
        if (repo / old).exists():
            if git:
                sh(repo, "git", "rm", "-q", old, dry=dry)
            elif not dry:
                (repo / old).unlink()
    for d in ("app/analysis", "app/demo", "app/cell"):
        p = repo / d
        if p.exists() and not dry:
            left = [x for x in p.rglob("*") if x.is_file() and "__pycache__" not in x.parts]
            if left:
                rep(f"LEFT IN {d}: {[str(x.relative_to(repo)) for x in left]}")


# --- 2. splits -----------------------------------------------------------------------------------------------
def node_names(node: ast.stmt) -> list[str]:
    if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
        return [node.name]
    if isinstance(node, ast.Assign):
        return [n.id for t in node.targets for n in ast.walk(t) if isinstance(n, ast.Name)]
    if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
        return [node.target.id]
    return []


def span(lines: list[str], node: ast.stmt) -> tuple[int, int]:
    """0-based [start, end) lines of a top-level node with its decorators and the comments right above it."""
    start = min([node.lineno] + [d.lineno for d in getattr(node, "decorator_list", [])]) - 1
    while start > 0 and lines[start - 1].lstrip().startswith("#"):
        start -= 1
    return start, node.end_lineno


def loads(nodes: list[ast.stmt]) -> set[str]:
    return {n.id for node in nodes for n in ast.walk(node) if isinstance(n, ast.Name)} | \
           {n.value.id for node in nodes for n in ast.walk(node)
            if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name)}


MOVED_BY_SPLIT: dict[tuple[str, str], str] = {}   # (old module, name) -> new module, incl. constants moved along
INSERTED: dict[Path, int] = {}   # per destination: the line after the last block a split inserted


def do_splits(repo: Path, moves, dry: bool, rep: Report) -> None:
    sym = symbol_table(moves)
    for old_mod, parts in SPLITS.items():
        cur_mod = moves.get(old_mod) or old_mod
        src = repo / (cur_mod.replace(".", "/") + ".py")
        if not src.exists():
            src = repo / cur_mod.replace(".", "/") / "__init__.py"
        if not src.exists():
            rep(f"SPLIT source missing: {old_mod} ({src})")
            continue
        text = src.read_text()
        lines = text.splitlines(keepends=True)
        tree = ast.parse(text)
        top = {n: node for node in tree.body for n in node_names(node)}
        header = [node for node in tree.body if isinstance(node, (ast.Import, ast.ImportFrom))]
        header_text = "".join("".join(lines[s:e]) for s, e in (span(lines, h) for h in header))
        cut: set[int] = set()
        taken: set[int] = set()                 # ids of nodes already moved by an earlier part
        moved_to: dict[str, str | None] = {}    # name -> its new module (None: deleted, defined elsewhere)
        for target, names in parts:
            missing = [n for n in names if n not in top]
            if missing:
                rep(f"SPLIT {old_mod}: not found at top level: {missing}")
            nodes = [top[n] for n in names if n in top and id(top[n]) not in taken]
            copies = []
            kept_consts: set[str] = set()
            # constants read by the moved code go with it (a logger is copied, not moved)
            for n in sorted(loads(nodes)):
                node = top.get(n)
                if node is None or node in nodes or not isinstance(node, (ast.Assign, ast.AnnAssign)):
                    continue
                if id(node) in taken:
                    continue
                if n in KEEP.get(old_mod, set()):
                    kept_consts.add(n)
                    continue
                if "getLogger" in ast.unparse(node):
                    copies.append(node)
                    continue
                nodes.append(node)
                rep(f"SPLIT {old_mod}: constant {n} moves with its users to {target}")
            own = {n for node in nodes for n in node_names(node)}
            defs_left = {n for n, node in top.items() if node not in nodes and id(node) not in taken
                         and isinstance(node, (ast.FunctionDef, ast.ClassDef, ast.AsyncFunctionDef))}
            back = sorted(loads(nodes) & defs_left) + sorted(kept_consts)
            earlier = sorted(n for n in loads(nodes) if n in moved_to and n not in own)
            if back and target is not None:
                rep(f"SPLIT {old_mod} -> {target}: the moved code reads {back}, which stays: imported from "
                    f"{cur_mod} (a circle if {cur_mod} imports {target}; move them too or pass them in)")
            nodes.sort(key=lambda n: n.lineno)
            body = "".join("".join(lines[slice(*span(lines, c))]) for c in copies) + ("\n\n" if copies else "")
            for node in nodes:
                s, e = span(lines, node)
                body += "".join(lines[s:e]) + "\n\n"
                cut.update(range(s, e))
                taken.add(id(node))
                for n in node_names(node):
                    moved_to[n] = target
                    if target is not None:
                        MOVED_BY_SPLIT[(old_mod, n)] = target
            if target is None:
                rep(f"SPLIT {old_mod}: deleted {names} (defined elsewhere)")
                continue
            print(f"split {old_mod}: {[node_names(n)[0] for n in nodes]} -> {target}")
            if dry:
                continue
            extra = ""
            if back:
                extra += f"from {old_mod} import {', '.join(back)}\n"
            for n in earlier:
                if moved_to[n] is not None:
                    extra += f"from {moved_to[n]} import {n}\n"
            dst = repo / (target.replace(".", "/") + ".py")
            dst.parent.mkdir(parents=True, exist_ok=True)
            if dst.exists():   # imports after the existing ones; the code before the module's own code (its
                cur = dst.read_text()   # module-level statements may use it), after what earlier parts brought
                ctree = ast.parse(cur)
                imp_end = max((n.end_lineno for n in ctree.body if isinstance(n, (ast.Import, ast.ImportFrom))),
                              default=0 if ast.get_docstring(ctree) is None else ctree.body[0].end_lineno)
                ins = max(imp_end, INSERTED.get(dst, 0))
                cl = cur.splitlines(keepends=True)
                hdr = (header_text.replace("from __future__ import annotations\n", "") + extra).splitlines(keepends=True)
                blk = ("\n\n" + body).splitlines(keepends=True)
                cl[ins:ins] = blk
                cl[imp_end:imp_end] = hdr
                INSERTED[dst] = ins + len(hdr) + len(blk)
                new_text = "".join(cl)
            else:
                doc = f'"""TODO(PLAN32): docstring. Split from {old_mod}."""\n\nfrom __future__ import annotations\n\n'
                new_text = doc + header_text.replace("from __future__ import annotations\n", "") + extra + "\n\n" + body
                INSERTED[dst] = len(new_text.rstrip("\n").splitlines()) + 1   # later parts go after this code
            dst.write_text(new_text.rstrip("\n") + "\n")
        if dry:
            continue
        kept = "".join(l for i, l in enumerate(lines) if i not in cut)
        # the remaining code may still use moved names: import them back from their new home
        tree2 = ast.parse(kept)
        used = loads(tree2.body)
        defined = {n for node in tree2.body for n in node_names(node)}
        by_target: dict[str, list[str]] = {}
        for n, target in moved_to.items():
            if n in used and n not in defined:
                home = target if target is not None else sym.get((old_mod, n))
                if home is None:
                    rep(f"SPLIT {old_mod}: {n} deleted but still used and not mapped")
                    continue
                by_target.setdefault(home, []).append(n)
        back_imports = [f"from {t} import {', '.join(sorted(ns))}\n" for t, ns in by_target.items()]
        if back_imports:
            last_import = max((node.end_lineno for node in tree2.body if isinstance(node, (ast.Import, ast.ImportFrom))),
                              default=0)
            kl = kept.splitlines(keepends=True)
            kept = "".join(kl[:last_import] + back_imports + kl[last_import:])
        src.write_text(re.sub(r"\n{4,}", "\n\n\n", kept))


def executed_names(node: ast.stmt) -> set[str]:
    """Names a top-level statement reads while the module is imported (not inside function bodies)."""
    out: set[str] = set()

    def visit(n: ast.AST, top: bool) -> None:
        if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for d in n.decorator_list + n.args.defaults + [x for x in n.args.kw_defaults if x is not None]:
                visit(d, False)
            return                                    # the body runs later
        if isinstance(n, ast.Lambda):
            return
        if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Load):
            out.add(n.id)
        for c in ast.iter_child_nodes(n):
            visit(c, False)

    visit(node, True)
    return out


def reorder(path: Path, rep: Report) -> None:
    """Order a split destination's top-level definitions so each comes after what it reads at import time
    (a stable topological sort; imports and the docstring stay first)."""
    text = path.read_text()
    tree = ast.parse(text)
    lines = text.splitlines(keepends=True)
    body = tree.body
    head = 0
    while head < len(body) and (isinstance(body[head], (ast.Import, ast.ImportFrom))
                                or (head == 0 and isinstance(body[head], ast.Expr))):
        head += 1
    rest = body[head:]
    if any(isinstance(n, (ast.Import, ast.ImportFrom)) for n in rest):
        rep(f"{path}: imports below code; not reordered (lift them first)")
        return
    spans = []
    prev_end = body[head - 1].end_lineno if head else 0
    for n in rest:
        s0, e0 = span(lines, n)
        s0 = max(s0, prev_end)
        spans.append((s0, e0))
        prev_end = e0
    defines = {name: i for i, n in enumerate(rest) for name in node_names(n)}
    needs = [{defines[x] for x in executed_names(n) if x in defines and defines[x] != i} for i, n in enumerate(rest)]
    order, done = [], set()
    while len(order) < len(rest):
        for i in range(len(rest)):
            if i not in done and needs[i] <= done:
                order.append(i)
                done.add(i)
                break
        else:
            rep(f"{path}: circular module-level dependencies between definitions; left as is")
            return
    if order == list(range(len(rest))):
        return
    start = spans[0][0] if spans else len(lines)
    out = lines[:start] + [x for i in order for x in ("".join(lines[spans[i][0]:spans[i][1]]).strip("\n") + "\n\n\n").splitlines(keepends=True)]
    path.write_text("".join(out).rstrip("\n") + "\n")
    rep(f"{path}: definitions reordered so each follows what it needs at import time")


# --- 4. imports ----------------------------------------------------------------------------------------------
def new_parts(mod: str, name: str, moves, sym) -> tuple[str, str]:
    """Where ``from mod import name`` comes from in the new tree: (module, name)."""
    full = f"{mod}.{name}"
    if full in moves and moves[full] is not None:   # a submodule imported from its package
        new = moves[full]
        parent, leaf = new.rsplit(".", 1)
        return parent, leaf
    for key in ((mod, name), (mod, "*")):
        if key in sym:
            return sym[key], name
    if mod in moves and moves[mod] is not None:
        return moves[mod], name
    return mod, name


def rewrite_imports(path: Path, text: str, moves, sym, rep: Report) -> str:
    tree = ast.parse(text)
    here = mod_of(str(path))
    lines = text.splitlines(keepends=True)
    edits: list[tuple[int, int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                rep(f"{path}:{node.lineno}: relative import left as is")
                continue
            mod = node.module or ""
            if mod.split(".")[0] not in ROOTS:
                continue
            groups: OrderedDict[str, list[str]] = OrderedDict()
            changed = False
            for a in node.names:
                if a.name == "*":
                    rep(f"{path}:{node.lineno}: star import left as is")
                    groups.setdefault(mod, []).append("*")
                    continue
                nmod, nname = new_parts(mod, a.name, moves, sym)
                if (mod in moves and moves[mod] is None and (mod, a.name) not in sym and (mod, "*") not in sym
                        and f"{mod}.{a.name}" not in moves):
                    rep(f"{path}:{node.lineno}: {mod}.{a.name}: module deleted and name not mapped")
                asname = a.asname or (a.name if nname != a.name else None)
                changed |= (nmod, nname) != (mod, a.name)
                if nmod == here:   # the name now lives in this very module (a split brought it here)
                    changed = True
                    continue
                groups.setdefault(nmod, []).append(nname + (f" as {asname}" if asname and asname != nname else ""))
            if not changed:
                continue
            first, last = node.lineno - 1, node.end_lineno - 1
            indent = lines[first][: len(lines[first]) - len(lines[first].lstrip())]
            tail = lines[last][node.end_col_offset:].rstrip("\n")
            head = lines[first][: node.col_offset]
            if head.strip() or (tail.strip() and not tail.strip().startswith("#")):
                rep(f"{path}:{node.lineno}: import shares its line with other code; left as is")
                continue
            out = [f"{indent}from {m} import {', '.join(ns)}" for m, ns in groups.items()]
            if not out:
                out = [f"{indent}pass"] if indent else [""]
            out[0] += tail
            edits.append((first, last + 1, "".join(o + "\n" for o in out)))
        elif isinstance(node, ast.Import):
            out, changed = [], False
            for a in node.names:
                name = a.name
                if name in moves and moves[name] is not None:
                    out.append(moves[name] + (f" as {a.asname}" if a.asname else ""))
                    changed = True
                else:
                    out.append(name + (f" as {a.asname}" if a.asname else ""))
            if changed:
                first, last = node.lineno - 1, node.end_lineno - 1
                indent = lines[first][: node.col_offset]
                if indent.strip():
                    rep(f"{path}:{node.lineno}: import shares its line; left as is")
                    continue
                tail = lines[last][node.end_col_offset:].rstrip("\n")
                edits.append((first, last + 1, f"{indent}import {', '.join(out)}{tail}\n"))
    for first, end, new in sorted(edits, reverse=True):
        lines[first:end] = [new]
    return "".join(lines)


def rewrite_module_aliases(repo: Path, path: Path, text: str, moves, sym, rep: Report) -> str:
    """``robust.default_workers`` where ``robust`` is a module bound in this file and ``default_workers`` left
    that module in a split: -> ``workers.default_workers`` + ``from calibration import workers``."""
    tree = ast.parse(text)
    rev = {new: old for old, new in moves.items() if new}
    is_mod = lambda m: (repo / (m.replace(".", "/") + ".py")).exists() or (repo / m.replace(".", "/")).is_dir()
    alias: dict[str, str] = {}
    for node in tree.body:
        if isinstance(node, ast.ImportFrom) and node.module and not node.level:
            for a in node.names:
                if is_mod(f"{node.module}.{a.name}"):
                    alias[a.asname or a.name] = f"{node.module}.{a.name}"
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.asname:
                    alias[a.asname] = a.name
    bound = {n for node in tree.body for n in node_names(node)} | \
            {(a.asname or a.name).split(".")[0] for node in tree.body if isinstance(node, (ast.Import, ast.ImportFrom))
             for a in node.names}
    lines = text.splitlines(keepends=True)
    edits, needed = [], {}
    for n in ast.walk(tree):
        if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name) and n.value.id in alias:
            new_mod = alias[n.value.id]
            old_mod = rev.get(new_mod, new_mod)
            target = sym.get((old_mod, n.attr))
            if target is None or target == new_mod:
                continue
            parent, leaf = target.rsplit(".", 1)
            if leaf in bound and alias.get(leaf) != target:
                rep(f"{path}:{n.lineno}: {n.value.id}.{n.attr} moved to {target}, but {leaf!r} is taken here: by hand")
                continue
            needed[leaf] = parent
            edits.append((n.value.lineno - 1, n.value.col_offset, n.value.end_col_offset, leaf))
    for ln, c0, c1, leaf in sorted(edits, reverse=True):
        lines[ln] = lines[ln][:c0] + leaf + lines[ln][c1:]
    if needed:
        at = max((x.end_lineno for x in tree.body if isinstance(x, (ast.Import, ast.ImportFrom))), default=0)
        add = [f"from {parent} import {leaf}\n" for leaf, parent in sorted(needed.items()) if alias.get(leaf) is None]
        lines[at:at] = add
    return "".join(lines)


# --- 5. dotted names and paths -------------------------------------------------------------------------------
def dotted_pattern(moves, sym) -> re.Pattern[str]:
    mods = {m for m, n in moves.items() if n != m} | {m for m, _ in sym}
    alt = "|".join(re.escape(m) for m in sorted(mods, key=len, reverse=True))
    return re.compile(r"(?<![\w.])(" + alt + r")(?:\.(\w+))?(?!\w)")


def rewrite_dotted(path: Path, text: str, moves, sym, pat, rep: Report) -> str:
    """Dotted module paths outside import statements: attribute chains, monkeypatch/mock strings, ``-m``
    arguments, docstrings and comments. Import lines were done by rewrite_imports and are skipped here."""
    try:
        tree = ast.parse(text)
        skip = {i for node in ast.walk(tree) if isinstance(node, (ast.Import, ast.ImportFrom))
                for i in range(node.lineno - 1, node.end_lineno)}
    except SyntaxError:
        skip = set()
    lines = text.splitlines(keepends=True)

    def repl(m: re.Match[str]) -> str:
        mod, name = m.group(1), m.group(2)
        if m.group(0) in STRING_OVERRIDES:
            return STRING_OVERRIDES[m.group(0)]
        if name and (mod, name) in sym:
            return f"{sym[(mod, name)]}.{name}"
        if name and f"{mod}.{name}" in moves:
            new = moves[f"{mod}.{name}"]
            return new if new else m.group(0)
        if mod in moves:
            if moves[mod] is None:
                rep(f"{path}: reference to deleted module {m.group(0)!r} left as is")
                return m.group(0)
            return moves[mod] + (f".{name}" if name else "")
        return m.group(0)

    for i, line in enumerate(lines):
        if i not in skip:
            lines[i] = pat.sub(repl, line)
    return "".join(lines)


def path_pattern(paths: dict[str, str]) -> re.Pattern[str]:
    alt = "|".join(re.escape(p) for p in sorted(paths, key=len, reverse=True))
    return re.compile(r"(?<![\w/])(" + alt + r")(?![\w])")


def rewrite_paths(text: str, paths: dict[str, str], pat: re.Pattern[str]) -> str:
    return pat.sub(lambda m: paths[m.group(1)], text)


# --- 6. parents[N] -------------------------------------------------------------------------------------------
PARENTS = re.compile(r"(Path\(__file__\)\.resolve\(\)\.parents\[)(\d+)(\])")


def fix_depth(text: str, old: str, new: str) -> str:
    d = new.count("/") - old.count("/")
    if not d:
        return text
    return PARENTS.sub(lambda m: f"{m.group(1)}{int(m.group(2)) + d}{m.group(3)}", text)


# --- main ----------------------------------------------------------------------------------------------------
def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repo", default=".")
    ap.add_argument("--dry-run", action="store_true")
    ap.add_argument("--split", action="store_true", help="also cut the top-level definitions of SPLITS")
    ap.add_argument("--no-git", action="store_true", help="plain renames instead of git mv/rm")
    ap.add_argument("--no-ruff", action="store_true")
    ap.add_argument("--rewrite-only", nargs="+", metavar="FILE",
                    help="after the move: place and rewrite these files (paths relative to --repo)")
    a = ap.parse_args(argv)
    repo = Path(a.repo).resolve()
    dry, git = a.dry_run, not a.no_git
    rep = Report()
    if a.rewrite_only:
        return rewrite_only(repo, a.rewrite_only, git, not a.no_ruff)
    if not (repo / "calibration/methods.py").exists():
        print("calibration/methods.py is gone: the move has run here already; refusing to run twice")
        return 2
    rows, moves, paths = load_table()
    sym = symbol_table(moves)
    for (m, name), real in second_paths(repo).items():   # one import path per name (before anything moves)
        if (m, name) not in sym:
            nmod, _ = new_parts(real, name, moves, sym)
            sym[(m, name)] = nmod
    old_paths = {new: old for old, new in paths.items()}

    do_moves(repo, rows, git, dry, rep)                       # 1
    if a.split:
        do_splits(repo, moves, dry, rep)                       # 2
    sym.update(MOVED_BY_SPLIT)                                 # constants that moved with their users
    if not dry:
        for dst in sorted({repo / (t.replace(".", "/") + ".py") for t in set(MOVED_BY_SPLIT.values())}):
            if dst.exists():
                reorder(dst, rep)
    do_deletes(repo, rows, git, dry, rep)                      # 3
    dpat, ppat = dotted_pattern(moves, sym), path_pattern(paths)
    for p in (py_files(repo) if not dry else []):              # 4-6
        rel = str(p.relative_to(repo))
        text = p.read_text()
        new = rewrite_imports(p.relative_to(repo), text, moves, sym, rep)
        new = rewrite_dotted(p.relative_to(repo), new, moves, sym, dpat, rep)
        new = rewrite_module_aliases(repo, p.relative_to(repo), new, moves, sym, rep)
        new = rewrite_paths(new, paths, ppat)
        if rel in old_paths:
            new = fix_depth(new, old_paths[rel], rel)
        if new != text:
            p.write_text(new)
    if dry:   # show what the import pass would do, file by file, on the unmoved tree
        for p in py_files(repo):
            text = p.read_text()
            new = rewrite_dotted(p.relative_to(repo), rewrite_imports(p.relative_to(repo), text, moves, sym, rep),
                                 moves, sym, dpat, rep)
            new = rewrite_paths(new, paths, ppat)
            if new != text:
                n = sum(1 for x, y in zip(text.splitlines(), new.splitlines()) if x != y)
                print(f"would rewrite {p.relative_to(repo)} (~{n} lines)")
    for f in TEXT_FILES:                                        # 5, non-Python
        p = repo / f
        if p.exists() and not dry:
            text = p.read_text()
            new = rewrite_paths(text, paths, ppat)
            new = dotted_pattern(moves, sym).sub(
                lambda m: STRING_OVERRIDES.get(m.group(0), (moves.get(m.group(1)) or m.group(1))
                                               + (f".{m.group(2)}" if m.group(2) else "")), new)
            if new != text:
                p.write_text(new)
    for old, new, note in rows:                                # 7 packages of the new tree
        target = new if old == "+new" else new
        if target == "-" or not target.startswith(("calibration/", "app/", "cell_config/")):
            continue
        for parent in Path(target).parents:
            if str(parent) in (".", "calibration", "app", "cell_config"):
                break
            init = repo / parent / "__init__.py"
            if not init.exists():
                print(f"create {init.relative_to(repo)}")
                if not dry:
                    init.parent.mkdir(parents=True, exist_ok=True)
                    init.write_text(f'"""TODO(PLAN32): what {parent} holds; re-exports with __all__."""\n')
        if old == "+new" and target.endswith(".py") and not (repo / target).exists():
            rep(f"TO WRITE by hand: {target}  ({note})")
    if not dry and not a.no_ruff:                               # 8
        try:
            subprocess.run(["ruff", "check", "--no-cache", "--select", "I,F401", "--fix", "--quiet",
                            *ROOTS], cwd=repo)
        except FileNotFoundError:
            rep("ruff not found: run `ruff check --select I,F401 --fix` yourself")
    if not dry:
        import json
        (HERE / "rewrite_map.json").write_text(json.dumps(
            {"moves": moves, "sym": sorted([m, n, t] for (m, n), t in sym.items()), "paths": paths}, indent=0) + "\n")
        (repo / "move-report.txt").write_text("\n".join(rep.lines) + "\n")
        print(f"\n{len(rep.lines)} notes in {repo / 'move-report.txt'}")
    return 0


def rewrite_only(repo: Path, files: list[str], git: bool, ruff: bool) -> int:
    """Rewrite files written for the old tree, with the map the move wrote (see the module docstring)."""
    import json
    data = json.loads((HERE / "rewrite_map.json").read_text())
    moves, paths = data["moves"], data["paths"]
    sym = {(m, n): t for m, n, t in data["sym"]}
    rep = Report()
    dpat, ppat = dotted_pattern(moves, sym), path_pattern(paths)
    done = []
    for f in files:
        rel = str(Path(f))
        if rel in paths and (repo / rel).exists():      # a file at its old path: to its new one first
            new_rel = paths[rel]
            if (repo / new_rel).exists():
                rep(f"{rel}: {new_rel} exists already; merge the two by hand")
                continue
            (repo / new_rel).parent.mkdir(parents=True, exist_ok=True)
            if git:
                subprocess.run(["git", "mv", rel, new_rel], cwd=repo, check=True)
            else:
                os.replace(repo / rel, repo / new_rel)
            old_rel, rel = rel, new_rel
        else:
            old_rel = None
            top = rel.split("/")[0]
            if top in ROOTS and mod_of(rel) in moves and moves[mod_of(rel)] != mod_of(rel):
                rep(f"{rel}: an old path whose module moved, but the file is not in the table: place it by hand")
            else:
                parts = mod_of(rel).split(".")
                pkgs = [".".join(parts[:i]) for i in range(len(parts) - 1, 0, -1)]
                gone = next((p for p in pkgs if p in moves and moves[p] != p), None)
                if top in ROOTS and (gone or not (repo / rel).parent.is_dir()):
                    rep(f"{rel}: its package {gone or Path(rel).parent} moved or is gone in the new tree: its "
                        f"imports are rewritten in place; git mv it to its room yourself (a row in table.tsv for "
                        f"the record) and fix a Path(__file__).parents[N] by the change of depth")
        p = repo / rel
        if not p.exists():
            rep(f"{rel}: not found")
            continue
        text = p.read_text()
        if rel.endswith(".py"):
            new = rewrite_imports(Path(rel), text, moves, sym, rep)
            new = rewrite_dotted(Path(rel), new, moves, sym, dpat, rep)
            new = rewrite_module_aliases(repo, Path(rel), new, moves, sym, rep)
            new = rewrite_paths(new, paths, ppat)
            if old_rel:
                new = fix_depth(new, old_rel, rel)
            done.append(rel)
        else:
            new = rewrite_paths(text, paths, ppat)
            new = dotted_pattern(moves, sym).sub(
                lambda m: STRING_OVERRIDES.get(m.group(0), (moves.get(m.group(1)) or m.group(1))
                                               + (f".{m.group(2)}" if m.group(2) else "")), new)
        if new != text:
            p.write_text(new)
            print(f"rewrote {rel}")
    if ruff and done:
        subprocess.run(["ruff", "check", "--no-cache", "--select", "I,F401", "--fix", "--quiet", *done], cwd=repo)
    return 0


if __name__ == "__main__":
    sys.exit(main())
