"""Alternate `import app.cli` between two trees N times; print the median CPU ms of each and the ratio."""
import statistics, subprocess, sys
A, B, N = sys.argv[1], sys.argv[2], int(sys.argv[3])
code = "import time; t=time.process_time(); import app.cli; print(1e3*(time.process_time()-t))"
res = {A: [], B: []}
for _ in range(N):
    for t in (A, B):
        out = subprocess.run(["/work/wt/move32/.venv/bin/python", "-c", code], env={"PYTHONPATH": t, "PATH": "/usr/bin"},
                             capture_output=True, text=True, cwd="/tmp")
        res[t].append(float(out.stdout))
ma, mb = statistics.median(res[A]), statistics.median(res[B])
print(f"before {ma:.1f} ms, after {mb:.1f} ms (median CPU of {N} alternating runs): {100 * (mb / ma - 1):+.1f} %")
