"""Every module of the product imports, in a fresh interpreter that walks the four packages and imports each module
in turn: a package ``__init__`` that runs into a circle, a name used before a split defined it, or a module that
needs an optional import nobody declared fails here rather than in a user's command. (The import contracts,
``lint-imports`` in ``make test``, hold the absence of circles; ``docs/dev/restructure/tools/import_alone.py``
imports each module with the others dropped, 7 to 10 s, too slow for a test.)"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

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
