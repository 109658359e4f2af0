"""First-screen screenshots of every report cellcal writes, for the docs (``docs/images/report_<kind>.png``).

Writes each report as a user would (the ``cellcal`` commands, in a temporary folder): ``demo`` on the simulated
cell, ``recalibrate`` on the simulated cell, and ``evaluate`` (a pi model on another recording: the extrapolation
warning), ``compare`` (nominal, base, nls1, pi, fbf13, fbf7: the instability warnings) and ``diagnose`` on the real R1
recordings of 0801 (``../shared/data/welding_motoman``), or on the demo's simulated R1 recordings when those are
absent. Then headless Chromium takes a 1280 x 800 shot of each page's first screen, quantised to 256 colours so each
file stays under 200 KB (the script fails otherwise).

    .venv/bin/python scripts/screenshot_reports.py [--out docs/images] [--keep DIR] [--browser chromium]

About 2.5 minutes on two busy cores (the compare of six methods on 0801 and the diagnosis take most of it).
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
WELDING = ROOT.parent / "shared" / "data" / "welding_motoman"
SIZE = (1280, 800)
MAX_BYTES = 200_000
KINDS = ("evaluate", "compare", "diagnose", "recalibrate", "demo")


def cellcal(work: Path, *argv: str) -> None:
    """Run ``cellcal argv`` (the venv's) in ``work`` (the outputs' names on the pages are short), its output passed
    through; a failure stops the script."""
    exe = Path(sys.executable).with_name("cellcal")
    print("$ cellcal " + " ".join(argv), flush=True)
    subprocess.run([str(exe), *argv], check=True, cwd=work)


def write_reports(work: Path) -> dict[str, Path]:
    """Every report kind written under ``work``; kind -> its report.html."""
    cellcal(work, "demo", "--out", "demo", "--anchor-step", "40", "--validation", "5", "--methods",
            "nominal,nls1,pi,fbf13", "--no-progress")
    if (WELDING / "PH_grad_data" / "test0801_R1").is_dir():
        train, test = WELDING / "PH_grad_data" / "test0801_R1", WELDING / "kinematic_raw_data" / "test0801_R1"
    else:
        print(f"{WELDING} not found: evaluate, compare and diagnose run on the demo's simulated R1 recordings")
        train, test = work / "demo" / "R1" / "train.csv", work / "demo" / "R1" / "test.csv"
    cellcal(work, "fit", "--robot", "R1", "--train", str(train), "--method", "pi", "--out", "pi.yaml")
    cellcal(work, "evaluate", "--model", "pi.yaml", "--test", str(test), "--report", "evaluate")
    cellcal(work, "compare", "--robot", "R1", "--train", str(train), "--test", str(test), "--methods",
            "nominal,base,nls1,pi,fbf13,fbf7", "--report", "compare")
    cellcal(work, "diagnose", "--robot", "R1", "--train", str(train), "--test", str(test), "--report", "diagnose")
    cellcal(work, "plan", "--robot", "R1", "--out", "plan.json", "--design", "grid", "--q2-step", "35", "--q3-step",
            "30")
    cellcal(work, "recalibrate", "--robot", "R1", "--plan", "plan.json", "--model-dir", "models", "--method", "nls1",
            "--validation", "12", "--validation-seed", "2", "--sim", "--time-scale", "200", "--no-progress", "--report",
            "recalibrate")
    return {k: work / k / "report.html" for k in KINDS}


def shoot(browser: str, html: Path, png: Path, work: Path, timeout_s: float = 90.0) -> None:
    """A first-screen PNG of ``html`` (headless Chromium, ``SIZE``)."""
    cmd = [browser, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--no-first-run",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           f"--user-data-dir={work / 'profile'}", f"--window-size={SIZE[0]},{SIZE[1]}", f"--screenshot={png}",
           "--virtual-time-budget=3000", html.as_uri()]
    with open(work / "browser.log", "w") as log:
        proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=log, stderr=log, start_new_session=True)
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)  # the browser this script started, and its helpers
            proc.wait()
    if not png.exists():
        raise SystemExit(f"{browser} wrote no screenshot of {html}: {(work / 'browser.log').read_text()[-1000:]}")


def small_png(src: Path, dst: Path) -> int:
    """``src`` quantised to 256 colours (text and flat boxes survive it) as ``dst``; its size [bytes]."""
    from PIL import Image

    with Image.open(src) as im:
        im.convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT).save(dst, optimize=True)
    return dst.stat().st_size


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(ROOT / "docs" / "images"), help="folder of the PNGs")
    ap.add_argument("--keep", help="write the reports into this folder (kept) instead of a temporary one")
    ap.add_argument("--browser", default=shutil.which("chromium") or "chromium", help="headless Chromium")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="cellcal-shots-") as tmp:
        work = Path(args.keep).resolve() if args.keep else Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        pages = write_reports(work)
        for kind, html in pages.items():
            raw = work / f"{kind}.png"
            shoot(args.browser, html, raw, work)
            n = small_png(raw, out / f"report_{kind}.png")
            print(f"{out / f'report_{kind}.png'}: {SIZE[0]}x{SIZE[1]}, {n / 1000:.0f} kB")
            if n > MAX_BYTES:
                raise SystemExit(f"{kind}: {n} bytes, over {MAX_BYTES}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
