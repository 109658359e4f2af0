#!/usr/bin/env python3
"""Golden files from today's main (PLAN32 §4, step 0): model files of every kind and the predictions they make,
so the new tree can prove it loads them and predicts bit for bit.

    cd /work/main && PYTHONPATH=. .venv/bin/python /work/wt/plan32/golden.py OUT_DIR [--plans]

Writes OUT_DIR/{constant,pi,cdc_fbf13,cdc_<kind>...,physics,diagnosed,rebased_<inner>}.{yaml,json},
OUT_DIR/q.npy (50 fixed configurations), OUT_DIR/predictions.npz (R, p of each file's model on q) and
OUT_DIR/manifest.json (file -> kind, method, schema). With --plans also a collection plan and a dual plan
(`cellcal plan`, `cellcal plan-dual --path sweep:200`; slower). Run on the old tree only (it imports old paths).

The test for the new tree (tests/calibration/models/test_saved_files.py) is:

    for name in manifest: m = load_model(dir / name); R, p = m.fk(q)
    np.testing.assert_array_equal(R, stored[name + ":R"]); np.testing.assert_array_equal(p, stored[name + ":p"])
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path.cwd()))
sys.path.insert(0, str(Path.cwd() / "tests" / "calibration"))

from calibration.interpolation import make_interpolator  # noqa: E402  (old tree paths, on purpose)
from calibration.models import load_model, save_model  # noqa: E402
from calibration.models.rebased import RebasedModel  # noqa: E402
from calibration.cdc import CdcModel  # noqa: E402
from kinds import T_BASE, T_TOOL, models_of_every_kind  # noqa: E402

FAST_INTERPOLATORS = ("fbf7", "rbf", "nearest", "linear", "cubic")   # nn/ae train networks: add if wanted


def main(argv: list[str]) -> int:
    out = Path(argv[0])
    out.mkdir(parents=True, exist_ok=True)
    k = models_of_every_kind()
    models = {"constant": k.constant, "pi": k.pi, "cdc_fbf13": k.cdc, "physics": k.physics, "diagnosed": k.diagnosed}
    rng = np.random.default_rng(7)
    x = rng.uniform(-1.5, 1.5, (40, 2))
    y = rng.normal(size=(40, k.par.size)) * k.par.scale() * 0.3
    for kind in FAST_INTERPOLATORS:
        try:
            interp = make_interpolator(kind).fit(x, y)
        except Exception as e:  # a kind's name differs on this tree: say so, go on
            print(f"skip interpolator {kind}: {e}")
            continue
        models[f"cdc_{kind}"] = CdcModel("R1", kind, k.kin, k.theta, interp)
    for inner in ("constant", "pi", "cdc_fbf13", "diagnosed"):
        m = models[inner]
        models[f"rebased_{inner}"] = RebasedModel(m.robot, m.method, m, T_BASE, T_TOOL, 12)
    lo, hi = np.radians([-60, -40, -40, -90, -60, -90]), np.radians([60, 40, 40, 90, 60, 90])
    q = rng.uniform(lo, hi, (50, 6))
    np.save(out / "q.npy", q)
    preds, manifest = {}, {}
    for name, m in models.items():
        for ext in ("yaml", "json"):
            f = out / f"{name}.{ext}"
            save_model(m, f)
            loaded = load_model(f)
            R, p = loaded.fk(q)
            preds[f"{f.name}:R"], preds[f"{f.name}:p"] = R, p
            manifest[f.name] = {"kind": loaded.kind, "method": loaded.method,
                                "schema": json.loads(json.dumps(loaded.to_dict()["schema"]))}
    np.savez(out / "predictions.npz", **preds)
    (out / "manifest.json").write_text(json.dumps(manifest, indent=1))
    print(f"{len(manifest)} model files in {out}")
    if "--plans" in argv:
        cli = [sys.executable, "-m", "app.cli"]
        subprocess.run(cli + ["plan", "--robot", "R1", "--out", str(out / "plan_collection.json")], check=True)
        subprocess.run(cli + ["plan-dual", "--path", "sweep:200", "--out", str(out / "plan_dual.json")], check=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
