"""Model files saved by an older main (0.1.0 at 3bdd962, before issue 32 moved the modules) keep loading and
predict bit for bit: a file stores kinds and schemas, never a module path, so moving code cannot orphan it.

``tests/data/saved_by_0_1_0/`` holds one model of every kind (constant, pi, cdc with six interpolators, physics,
diagnosed, rebased around four inner kinds), each as YAML and JSON, the 50 joint configurations ``q.npy`` and the
poses the saving tree predicted there (``predictions.npz``), written on the 0.1.0 tree by the restructure's one-off
``golden.py`` (``docs/dev/restructure/tools/golden.py`` in git history up to 2e3c160).
"""

from __future__ import annotations

import importlib
import json
from pathlib import Path

import numpy as np
import pytest

from calibration.models import load_model
from calibration.models.registry import KIND_MODULES, KINDS

SAVED = Path(__file__).resolve().parents[2] / "data" / "saved_by_0_1_0"
MANIFEST = json.loads((SAVED / "manifest.json").read_text())


@pytest.fixture(scope="module")
def saved():
    return np.load(SAVED / "q.npy"), np.load(SAVED / "predictions.npz")


@pytest.mark.parametrize("name", sorted(MANIFEST))
def test_a_file_saved_by_0_1_0_loads_and_predicts_bit_for_bit(name, saved):
    q, stored = saved
    model = load_model(SAVED / name)
    R, p = model.fk(q)
    assert model.kind == MANIFEST[name]["kind"] and model.method == MANIFEST[name]["method"]
    assert np.array_equal(R, stored[f"{name}:R"]) and np.array_equal(p, stored[f"{name}:p"])


def test_the_saved_files_cover_every_model_kind():
    assert {meta["kind"] for meta in MANIFEST.values()} == set(KIND_MODULES)


def test_the_kind_names_are_frozen_and_each_module_registers_its_kind():
    # the kind names are what files store: renaming one orphans every file of that kind
    assert set(KIND_MODULES) == {"constant", "cdc", "pi", "physics", "diagnosed", "rebased"}
    for module in KIND_MODULES.values():
        importlib.import_module(module)
    assert {k: KINDS[k].__module__ for k in KIND_MODULES} == KIND_MODULES
