"""Static check of a (moved) tree: every `from X import n` and every `alias.n` on a project module names
something X defines or imports at top level (or a submodule). Usage: python check_names.py TREE"""
import ast, sys
from pathlib import Path
repo = Path(sys.argv[1]); ROOTS = ("calibration", "app", "drivers", "cell_config", "scripts", "tests")
def mod_of(p):
    parts = list(p.relative_to(repo).with_suffix("").parts)
    if parts[-1] == "__init__": parts = parts[:-1]
    return ".".join(parts)
files = {mod_of(p): p for r in ROOTS for p in (repo / r).rglob("*.py") if "__pycache__" not in p.parts}
def is_pkg(m): return (repo / m.replace(".", "/")).is_dir()
names = {}
for m, p in files.items():
    t = ast.parse(p.read_text()); ns = set()
    for node in ast.walk(t) if False else t.body:
        for sub in ast.walk(node) if isinstance(node, (ast.If, ast.Try)) else [node]:
            if isinstance(sub, (ast.FunctionDef, ast.ClassDef, ast.AsyncFunctionDef)): ns.add(sub.name)
            elif isinstance(sub, ast.Assign):
                ns |= {x.id for tg in sub.targets for x in ast.walk(tg) if isinstance(x, ast.Name)}
            elif isinstance(sub, ast.AnnAssign) and isinstance(sub.target, ast.Name): ns.add(sub.target.id)
            elif isinstance(sub, (ast.Import, ast.ImportFrom)):
                ns |= {(a.asname or a.name).split(".")[0] for a in sub.names}
    names[m] = ns
bad = []
for m, p in files.items():
    t = ast.parse(p.read_text()); alias = {}
    for node in ast.walk(t):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] in ROOTS[:4] + ("scripts", "tests"):
            for a in node.names:
                full = f"{node.module}.{a.name}"
                if full in files or is_pkg(full):
                    alias[a.asname or a.name] = full; continue
                if node.module not in files and not is_pkg(node.module):
                    bad.append(f"{p.relative_to(repo)}:{node.lineno}: no module {node.module}"); continue
                if node.module in files and a.name not in names[node.module] and a.name != "*":
                    bad.append(f"{p.relative_to(repo)}:{node.lineno}: {node.module} has no {a.name}")
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.asname and a.name in files: alias[a.asname] = a.name
    for node in ast.walk(t):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in alias:
            tm = alias[node.value.id]
            if tm in files and node.attr not in names[tm] and f"{tm}.{node.attr}" not in files:
                bad.append(f"{p.relative_to(repo)}:{node.lineno}: {node.value.id}.{node.attr}: {tm} has no {node.attr}")
print(len(bad), "unresolved names"); print("\n".join(sorted(set(bad))))
