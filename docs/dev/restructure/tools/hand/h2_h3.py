"""Hand steps H3 (days) and H2 (design) as patches on the moved tree, enough to make every module import.
H3: DaysProblem.solve() returns (x, own); daydiff calls DaysResult.build(problem, *problem.solve()).
H2: identification/design.py:select_recording loses its rebase branch, which becomes
    frames/rebase_design.py:select_rebase_recording (same arguments, same figures)."""
import re, sys
from pathlib import Path
repo = Path(sys.argv[1] if len(sys.argv) > 1 else ".")
# --- H3 ---
dp = repo / "calibration/frames/days_problem.py"
t = dp.read_text()
t = t.replace("from calibration.frames.daydiff import DaysResult\n", "")
t = t.replace('def solve(self) -> "DaysResult":', "def solve(self) -> tuple[np.ndarray, list[np.ndarray]]:")
t = t.replace("return DaysResult.build(self, x, own)", "return x, own  # DaysResult.build(problem, x, own) in daydiff")
dp.write_text(t)
dd = repo / "calibration/frames/daydiff.py"
t = dd.read_text()
t = re.sub(r"DaysProblem\(([^\n]*?)\)\.solve\(\)", lambda m: f"_solved(DaysProblem({m.group(1)}))", t)
t += '''

def _solved(problem: DaysProblem) -> "DaysResult":
    """The problem solved, as a result (the problem module does not know the result type)."""
    x, own = problem.solve()
    return DaysResult.build(problem, x, own)
'''
dd.write_text(t)
# --- H2 ---
de = repo / "calibration/identification/design.py"
t = de.read_text()
t = t.replace("from calibration.frames.rebase_design import rebase_candidates\n", "")
t = t.replace("from calibration.models import ConstantModel\n", "")
m = re.search(r"\n    if rebase_offsets is None:\n(.*?)\n    else:\n(.*?)\n    chosen = ", t, re.S)
if m:
    t = t[:m.start()] + "\n" + re.sub(r"^    ", "", m.group(1), flags=re.M) + "\n    chosen = " + t[m.end():]
    t = t.replace("spread_weight: float = DEFAULT_SPREAD_WEIGHT, rebase_offsets: tuple[int, ...] | None = None\n",
                  "spread_weight: float = DEFAULT_SPREAD_WEIGHT\n")
de.write_text(t)
rd = repo / "calibration/frames/rebase_design.py"
r = rd.read_text()
r += '''

def select_rebase_recording(par: "MinimalParameterisation", rec: "Recording", budget: int, noise_mm: float,
                            rebase_offsets: tuple[int, ...], cluster_size: int = 7,
                            a: float = DEFAULT_ORIENTATION_WEIGHT) -> "RecordingSelection":
    """TODO(PLAN32, H2): select_recording's rebase branch, moved here unchanged (D on the rebase's frame
    directions and ``rebase_offsets`` at the nominal arm, no spread term)."""
    raise NotImplementedError("H2: move the branch body here from git history (identification/design.py)")
'''
rd.write_text(r)
print("H2/H3 patched (H2 body left as a TODO stub)")
