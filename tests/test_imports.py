"""Every module of the product imports, in a fresh interpreter that walks the four packages and imports each module
in turn: a package ``__init__`` that runs into a circle, a name used before a split defined it, or a module that
needs an optional import nobody declared fails here rather than in a user's command. (The import contracts,
``lint-imports`` in ``make test``, hold the absence of circles, and the import drawing of the docs site is checked against them below.)"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from conftest import gen_pages

ROOT = Path(__file__).resolve().parents[1]

WALK = """
import importlib, pkgutil
roots = ("calibration", "cell_config", "drivers", "app")
names, fails = [], []
for root in roots:
    pkg = importlib.import_module(root)
    names += [root] + [m.name for m in pkgutil.walk_packages(pkg.__path__, root + ".", onerror=fails.append)
                       if not m.name.endswith("__main__")]
for name in names:
    try:
        importlib.import_module(name)
    except Exception as e:
        fails.append(f"{name}: {type(e).__name__}: {e}")
print(len(names))
print("\\n".join(map(str, fails)))
"""


def test_every_module_of_the_product_imports():
    out = subprocess.run([sys.executable, "-c", WALK], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    count, *fails = out.stdout.strip().splitlines()
    assert int(count) > 150 and not fails, fails


def _layers(container: str | None) -> list[set[str]]:
    import tomllib

    contracts = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    for contract in contracts:
        if contract["type"] == "layers" and contract.get("containers", [None]) == [container]:
            return [{name.strip() for name in layer.split("|")} for layer in contract["layers"]]
    raise AssertionError(f"no layers contract for {container}")


def _rank(layers: list[set[str]], name: str) -> int:
    return next(i for i, layer in enumerate(layers) if name in layer)


def test_the_import_drawing_agrees_with_the_contracts_and_has_no_circle():
    """The drawing on the docs site (reference/imports.md) is made from the same graph engine as ``lint-imports``;
    every arrow it draws between the top packages and between calibration's and app's folders points down the
    layers pyproject.toml declares, and the folders of drivers/ and cell_config/ form no circle."""
    from graphlib import CycleError, TopologicalSorter

    edges = gen_pages().folder_edges()
    assert edges, "no import drawn"
    top = _layers(None)
    for (a, b) in edges:
        if "." not in a:
            assert _rank(top, a) < _rank(top, b), f"{a} -> {b} goes up the product's layers"
    for container in ("calibration", "app"):
        layers = _layers(container)
        for (a, b) in edges:
            if a.startswith(container + "."):
                la, lb = _rank(layers, a.split(".")[1]), _rank(layers, b.split(".")[1])
                assert la < lb, f"{a} -> {b} is drawn against the layers of {container}"
    graph: dict[str, set[str]] = {}
    for (a, b) in edges:
        graph.setdefault(a, set()).add(b)
    try:
        tuple(TopologicalSorter(graph).static_order())
    except CycleError as e:  # pragma: no cover - the failure message
        raise AssertionError(f"import circle between folders: {e.args[1]}") from e
    page = gen_pages().imports_page()
    assert page.count("```mermaid") == 1 + sum(any(a.startswith(p + ".") for a, _ in edges)
                                               for p in ("calibration", "cell_config", "drivers", "app"))


def test_the_tests_have_one_conftest():
    """Test modules import helpers with ``from conftest import ...`` (tests/ has no ``__init__.py``): a second
    ``conftest.py`` in a subfolder takes that name first for the modules below it and breaks their imports."""
    found = sorted(p.relative_to(ROOT).as_posix() for p in (ROOT / "tests").rglob("conftest.py"))
    assert found == ["tests/conftest.py"], found
