"""Load every golden file with the tree on PYTHONPATH and compare predictions bit for bit.
    PYTHONPATH=TREE python check_golden.py GOLDEN_DIR"""
import json, sys
from pathlib import Path
import numpy as np
from calibration.models import load_model
import calibration
d = Path(sys.argv[1]); q = np.load(d / "q.npy"); stored = np.load(d / "predictions.npz")
manifest = json.loads((d / "manifest.json").read_text()); bad = []
for name, meta in manifest.items():
    m = load_model(d / name)
    R, p = m.fk(q)
    if m.kind != meta["kind"] or not (np.array_equal(R, stored[f"{name}:R"]) and np.array_equal(p, stored[f"{name}:p"])):
        bad.append(name)
print(calibration.__file__, f"{len(manifest) - len(bad)}/{len(manifest)} files load and predict bit for bit", bad)
