"""Compare two step-0 output folders: every JSON equal except timing and path fields (listed)."""
import json, re, sys
from pathlib import Path
A, B = Path(sys.argv[1]), Path(sys.argv[2])
TIMING = re.compile(r"(seconds|_ms|_s$|_s_|time|elapsed|duration|per_s|throughput|wall|cpu)", re.I)
def walk(a, b, path, out):
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if TIMING.search(str(k)):
                continue
            if k not in a or k not in b:
                out.append(f"{path}/{k}: only in {'after' if k in b else 'before'}"); continue
            walk(a[k], b[k], f"{path}/{k}", out)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            out.append(f"{path}: list length {len(a)} != {len(b)}"); return
        for i, (x, y) in enumerate(zip(a, b)):
            walk(x, y, f"{path}[{i}]", out)
    elif a != b:
        if isinstance(a, str) and isinstance(b, str) and ("/src_" in a or "/before" in a or "/after" in a):
            return  # a path of the run
        out.append(f"{path}: {a!r} != {b!r}")
for f in sorted(A.glob("*.json")):
    g = B / f.name
    if not g.exists():
        print(f.name, "MISSING after"); continue
    out = []
    walk(json.loads(f.read_text()), json.loads(g.read_text()), "", out)
    print(f"{f.name}: {'identical (timings and run paths aside)' if not out else str(len(out)) + ' differences'}")
    for o in out[:15]:
        print("   ", o)
