"""Import graph of the cellcal product (read-only on the repo).

Usage: /work/main/.venv/bin/python imports.py [REPO] > out
Writes JSON to imports.json beside this file and prints a report.
Edge semantics follow grimp/import-linter: `from a.b import c` is an edge to a.b.c when that is a module,
else to a.b; `import a.b` is an edge to a.b. Kinds: 'module' (executed at import, incl. try/if at top),
'typing' (under `if TYPE_CHECKING`), 'local' (inside a def/lambda), 'class' (class body, top level).
"""
import ast, json, os, sys
from collections import defaultdict

REPO = sys.argv[1] if len(sys.argv) > 1 else "/work/main"
ROOTS = ["calibration", "app", "drivers", "cell_config", "scripts", "tests"]


def modname(path):
    rel = os.path.relpath(path, REPO)[:-3].split(os.sep)
    if rel[-1] == "__init__":
        rel = rel[:-1]
    return ".".join(rel)


def collect_modules():
    mods = {}
    for r in ROOTS:
        for d, dirs, files in os.walk(os.path.join(REPO, r)):
            dirs[:] = [x for x in dirs if x != "__pycache__"]
            for f in files:
                if f.endswith(".py"):
                    p = os.path.join(d, f)
                    mods[modname(p)] = p
    return mods


def resolve(mods, cur, is_pkg, node):
    """Return list of (target_module, names) for an import node."""
    out = []
    if isinstance(node, ast.Import):
        for a in node.names:
            out.append((a.name, None))
        return out
    base = node.module or ""
    if node.level:
        parts = cur.split(".")
        if not is_pkg:
            parts = parts[:-1]
        if node.level > 1:
            parts = parts[: len(parts) - (node.level - 1)]
        base = ".".join(parts + ([base] if base else []))
    for a in node.names:
        sub = f"{base}.{a.name}" if base else a.name
        if sub in mods:
            out.append((sub, None))
        else:
            out.append((base, a.name))
    return out


class V(ast.NodeVisitor):
    def __init__(self, mods, cur, is_pkg):
        self.mods, self.cur, self.is_pkg = mods, cur, is_pkg
        self.stack = []  # 'def' / 'class' / 'typing'
        self.edges = []  # (target, kind, lineno, name, func)
        self.funcs = []
        self.getattr_ = False

    def kind(self):
        if "def" in self.stack:
            return "local"
        if "typing" in self.stack:
            return "typing"
        if "class" in self.stack:
            return "class"
        return "module"

    def _imp(self, node):
        for tgt, name in resolve(self.mods, self.cur, self.is_pkg, node):
            self.edges.append((tgt, self.kind(), node.lineno, name, ".".join(self.funcs)))

    visit_Import = _imp
    visit_ImportFrom = _imp

    def visit_If(self, node):
        t = node.test
        tc = (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
            isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING")
        if tc:
            self.stack.append("typing")
            for s in node.body:
                self.visit(s)
            self.stack.pop()
            for s in node.orelse:
                self.visit(s)
        else:
            self.generic_visit(node)

    def _def(self, node):
        if not self.stack and node.name == "__getattr__":
            self.getattr_ = True
        self.stack.append("def")
        self.funcs.append(node.name)
        self.generic_visit(node)
        self.funcs.pop()
        self.stack.pop()

    visit_FunctionDef = visit_AsyncFunctionDef = _def

    def visit_Lambda(self, node):
        self.stack.append("def")
        self.generic_visit(node)
        self.stack.pop()

    def visit_ClassDef(self, node):
        self.stack.append("class")
        self.funcs.append(node.name)
        self.generic_visit(node)
        self.funcs.pop()
        self.stack.pop()


def tarjan(nodes, adj):
    index, low, on, st, res, i = {}, {}, set(), [], [], [0]
    sys.setrecursionlimit(10000)

    def sc(v):
        index[v] = low[v] = i[0]; i[0] += 1; st.append(v); on.add(v)
        for w in adj.get(v, ()):
            if w not in index:
                sc(w); low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = st.pop(); on.discard(w); comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                res.append(sorted(comp))

    for v in sorted(nodes):
        if v not in index:
            sc(v)
    return res


def main():
    mods = collect_modules()
    data = {}
    for m, p in sorted(mods.items()):
        src = open(p).read()
        tree = ast.parse(src)
        v = V(mods, m, p.endswith("__init__.py"))
        v.visit(tree)
        internal = [e for e in v.edges if e[0].split(".")[0] in ROOTS]
        data[m] = {"path": os.path.relpath(p, REPO), "lines": src.count("\n"), "getattr": v.getattr_,
                   "edges": [list(e) for e in internal],
                   "external": sorted({e[0].split(".")[0] for e in v.edges if e[0].split(".")[0] not in ROOTS})}
    json.dump(data, open(os.environ.get("IMPORTS_JSON") or os.path.join(os.path.dirname(os.path.abspath(__file__)), "imports.json"), "w"), indent=0)
    return mods, data


if __name__ == "__main__":
    main()
