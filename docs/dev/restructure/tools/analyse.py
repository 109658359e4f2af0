#!/usr/bin/env python3
"""Strongly connected components (import circles) of the product in an imports.json written by imports.py.

    IMPORTS_JSON=FILE python analyse.py summary

Four lines: module-level imports only; + `if TYPE_CHECKING`; + function-local; everything (+ class bodies).
Only calibration/, app/, drivers/, cell_config/ count (scripts and tests import the product, never the reverse).
Also prints the number of function-local import edges between product modules."""
import json
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from imports import tarjan  # noqa: E402

PRODUCT = ("calibration", "app", "drivers", "cell_config")
data = json.load(open(os.environ.get("IMPORTS_JSON") or Path(__file__).resolve().parent / "imports.json"))
nodes = [m for m in data if m.split(".")[0] in PRODUCT]
for label, kinds in (("module-level", {"module"}), ("module-level + TYPE_CHECKING", {"module", "typing"}),
                     ("module-level + function-local", {"module", "local"}),
                     ("every import", {"module", "typing", "local", "class"})):
    adj = {m: sorted({e[0] for e in data[m]["edges"] if e[1] in kinds and e[0] in data and e[0] != m}) for m in nodes}
    sccs = tarjan(nodes, adj)
    print(f"## {label}: {len(sccs)} SCC(s) {[len(s) for s in sccs]}")
    for s in sccs:
        print("   ", ", ".join(s))
local = [(m, e[0]) for m in nodes for e in data[m]["edges"] if e[1] == "local" and e[0].split(".")[0] in PRODUCT]
print(f"## function-local import edges between product modules: {len(local)}")
for m, t in local:
    print("   ", m, "->", t)
