"""Replay the bad-input families of issue 30 through the real CLI, each case a subprocess with a timeout.

Families: recordings, model files, cell files, plan files, output paths, options, session databases, JBI jobs. Every
bad input is generated here (in a temporary folder) from a small synthetic recording of the packaged R1, a model
fitted on it, a collection plan, a dual plan, the packaged cell, a session made through the session store and a
JBI job. Each case runs ``python -m app.cli ...`` and is judged:

- **clean**: exit 2 with one line on stderr (``warning:`` lines aside) and no traceback;
- **traceback**: a Python traceback on stderr, or an exit code other than 0, 2 and 130;
- **hang**: still running at the timeout (killed);
- **wrote on failure**: a failed case (exit != 0) left an output file it was given, or changed one that existed;
- **marked**: exit 0 printing the mark the case expects (``preview`` draws an unsafe plan, marks each unsafe
  waypoint red and lists it on stderr: issue 30 asks it to show, not refuse);
- **accepted**: exit 0 (a case the spec allows, or a check missing: listed so a reader can tell which);
- **unclear**: exit 2 with more than one line on stderr.

Prints tried / clean exit 2 / marked / accepted / traceback / hang / wrote on failure / unclear per family and in total, then
every case that was not clean. Exit 1 when any case is a traceback, a hang or wrote on failure.

    python scripts/studies/replay_bad_inputs.py [--json FILE] [--families recordings,plans,...] [--timeout-s 30]
                                        [--case 'FAMILY: NAME' ...] [--list]
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import os
import shutil
import sqlite3
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

FAMILIES = ("recordings", "models", "cells", "plans", "outputs", "options", "sessions", "jobs")


@dataclass
class Case:
    """One bad input: ``argv`` (after ``cellcal``) with ``{W}`` standing for the work folder; ``outputs`` the output
    paths it names (judged for writes on failure); ``setup`` makes its input in the work folder first."""

    family: str
    name: str
    argv: list[str]
    outputs: list[str] = field(default_factory=list)
    setup: Callable[[Path], None] | None = None
    note: str = ""
    marks: str = ""  # text an exit 0 must print on stderr to count as handled (preview draws and marks, by design)


@dataclass
class Outcome:
    family: str
    name: str
    verdict: str
    code: int | None
    seconds: float
    stderr: str
    wrote: list[str]


# -- the good inputs the bad ones are made from ------------------------------------------------------------------------

def make_base(w: Path) -> None:
    """A small synthetic R1 recording, a model fitted on it, joints, a collection plan, a dual plan, a copy of the
    packaged cell, a session and a JBI job."""
    from app.collection.plans.collection import Plan
    from app.collection.session_store import Sample, SessionStore
    from calibration.data.recording import Recording, write_recording
    from calibration.kinematics import so3
    from cell_config import DEFAULT_CELL, load_cell

    cell = load_cell()
    nominal = cell.robot("R1").model()
    rng = np.random.default_rng(0)
    anchors = [[a, q2, q3, b, c, d] for q2 in (-30.0, 0.0, 30.0) for q3 in (-30.0, 0.0, 20.0)
               for a, b, c, d in [rng.uniform(-30, 30, 4)]]
    q = np.radians(np.repeat(anchors, 7, axis=0) + np.tile(np.vstack([np.zeros(6), np.eye(6)]), (len(anchors), 1)))
    R, p = nominal.fk(q)
    p = p + rng.normal(0, 0.05, p.shape)
    rec = Recording(q, p, so3.R_to_quat(R), {"cluster": np.repeat(np.arange(len(anchors)), 7).astype(float)}, "")
    write_recording(rec, w / "train.csv")
    np.savetxt(w / "q.csv", q[:5], delimiter=",")
    shutil.copytree(Path(DEFAULT_CELL).parent, w / "cell", ignore=shutil.ignore_patterns("__pycache__", "*.py"))
    from app.cli.commands import main as cellcal  # in this process: the good inputs are no case

    for argv in (["fit", "--robot", "R1", "--train", str(w / "train.csv"), "--method", "nls1", "--out",
                  str(w / "m.yaml")],
                 ["plan", "--design", "grid", "--robot", "R1", "--q2-step", "60", "--q3-step", "60", "--out",
                  str(w / "plan.json")],
                 ["plan-dual", "--path", "sweep:5", "--out", str(w / "dual.json")]):
        with contextlib.redirect_stdout(sys.stderr):  # stdout is the table
            code = cellcal(["--quiet", *argv])
        if code != 0:
            raise RuntimeError(f"the good input of cellcal {' '.join(argv)} was refused")
    plan = Plan.from_dict(json.loads((w / "plan.json").read_text()), "plan")
    with SessionStore(w / "session", create=True) as store:
        store.init(plan, {"robot": "R1"})
        for i in range(3):
            store.add_sample(Sample(i, q[i], p[i], rec.quat[i], 0.01, 0.01, 0.1, 10, float(i), np.zeros(6)),
                             "R1", "anchor", 0)
    pulses = [",".join(str(v) for v in cell.robot("R1").robot.to_pulses(qq)) for qq in q[:3]]
    lines = ["/JOB", "//NAME SPRAY1", "//POS", "///NPOS 3,0,0,0,0,0", "///TOOL 0", "///POSTYPE PULSE", "///PULSE",
             *(f"C{i:05d}={v}" for i, v in enumerate(pulses)), "//INST", "///DATE 2026/12/01 12:00",
             "///ATTR SC,RW", "///GROUP1 RB1", "NOP", "MOVJ C00000 VJ=10.00", "MOVL C00001 V=50.0",
             "MOVL C00002 V=50.0", "END"]
    (w / "IN.JBI").write_bytes("".join(line + "\r\n" for line in lines).encode("ascii"))


def run(argv: list[str], timeout_s: float = 120.0) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-m", "app.cli", *argv], capture_output=True, text=True, cwd=ROOT,
                          timeout=timeout_s, env=env, stdin=subprocess.DEVNULL, check=False)


# -- helpers that make bad files ----------------------------------------------------------------------------------

def text(name: str, content: str | bytes) -> Callable[[Path], None]:
    def make(w: Path) -> None:
        (w / name).write_bytes(content if isinstance(content, bytes) else content.encode())
    return make


def fifo(name: str) -> Callable[[Path], None]:
    def make(w: Path) -> None:
        if not (w / name).exists():
            os.mkfifo(w / name)
    return make


def sparse(name: str, size: int) -> Callable[[Path], None]:
    """A file of ``size`` bytes that takes no disk (its size is what a bound must refuse)."""
    def make(w: Path) -> None:
        with open(w / name, "wb") as f:
            f.truncate(size)
    return make


def edited(src: str, name: str, edit: Callable[[str], str]) -> Callable[[Path], None]:
    def make(w: Path) -> None:
        (w / name).write_text(edit((w / src).read_text()))
    return make


def recording_rows(name: str, edit: Callable[[list[str]], list[str]]) -> Callable[[Path], None]:
    return edited("train.csv", name, lambda t: "\n".join(edit(t.splitlines())) + "\n")


def set_field(row: int, column: str, value: str) -> Callable[[list[str]], list[str]]:
    def edit(lines: list[str]) -> list[str]:
        names = lines[0].split(",")
        cells = lines[row].split(",")
        cells[names.index(column)] = value
        return lines[:row] + [",".join(cells)] + lines[row + 1:]
    return edit


def scaled(name: str, factor: float) -> Callable[[Path], None]:
    def make(w: Path) -> None:
        from calibration.data.recording import Recording, read_recording, write_recording

        r = read_recording(w / "train.csv")
        write_recording(Recording(r.q, r.p * factor, r.quat, r.extra, ""), w / name)
    return make


def quat_xyzw(name: str) -> Callable[[Path], None]:
    def make(w: Path) -> None:
        from calibration.data.recording import Recording, read_recording, write_recording

        r = read_recording(w / "train.csv")
        write_recording(Recording(r.q, r.p, np.roll(r.quat, -1, axis=1), r.extra, ""), w / name)
    return make


def subset(name: str, rows: list[int] | np.ndarray, same: bool = False) -> Callable[[Path], None]:
    def make(w: Path) -> None:
        from calibration.data.recording import Recording, read_recording, write_recording

        r = read_recording(w / "train.csv").subset(np.asarray(rows))
        if same:
            r = Recording(r.q, r.p, r.quat, {"cluster": np.arange(len(r)) // 7 * 1.0}, "")
        write_recording(r, w / name)
    return make


def yaml_edit(name: str, edit: Callable[[dict], object]) -> Callable[[Path], None]:
    def make(w: Path) -> None:
        import yaml

        d = yaml.safe_load((w / "m.yaml").read_text())
        (w / name).write_text(yaml.safe_dump(edit(d)))
    return make


def json_edit(src: str, name: str, edit: Callable[[dict], object]) -> Callable[[Path], None]:
    def make(w: Path) -> None:
        (w / name).write_text(json.dumps(edit(json.loads((w / src).read_text()))))
    return make


def cell_edit(name: str, edit: Callable[[str], str]) -> Callable[[Path], None]:
    def make(w: Path) -> None:
        (w / "cell" / name).write_text(edit((w / "cell" / "cell.yaml").read_text()))
    return make


def session_sql(name: str, sql: str) -> Callable[[Path], None]:
    def make(w: Path) -> None:
        shutil.copytree(w / "session", w / name)
        with sqlite3.connect(w / name / "session.sqlite") as con:
            con.execute(sql)
        con.close()
    return make


def session_file(name: str, content: bytes | None) -> Callable[[Path], None]:
    def make(w: Path) -> None:
        (w / name).mkdir()
        if content is None:
            os.mkfifo(w / name / "session.sqlite")
        else:
            (w / name / "session.sqlite").write_bytes(content)
    return make


def with_item(d: dict, path: list, value: object) -> dict:
    target = d
    for k in path[:-1]:
        target = target[k]
    target[path[-1]] = value
    return d


# -- the cases ---------------------------------------------------------------------------------------------------------

def cases() -> list[Case]:
    out: list[Case] = []

    def fit(name: str, train: str, setup=None, method: str = "nls1", note: str = "") -> None:
        out.append(Case("recordings", name, ["fit", "--robot", "R1", "--train", train, "--method", method, "--out",
                                             "{W}/out/m.yaml", "--json", "{W}/out/m.json"],
                        ["{W}/out/m.yaml", "{W}/out/m.json"], setup, note))

    header = "q1,q2,q3,q4,q5,q6,x,y,z,qw,qx,qy,qz"
    fit("missing file", "{W}/nothing.csv")
    fit("empty file", "{W}/empty.csv", text("empty.csv", ""))
    fit("header only", "{W}/header.csv", text("header.csv", header + "\n"))
    fit("a required column missing", "{W}/nocol.csv", recording_rows("nocol.csv", lambda ls: [
        ",".join(c for c in l.split(",")[:12]) for l in ls]))
    fit("non-numeric value", "{W}/word.csv", recording_rows("word.csv", set_field(3, "x", "abc")))
    fit("nan value", "{W}/nan.csv", recording_rows("nan.csv", set_field(3, "q2", "nan")))
    fit("inf value", "{W}/inf.csv", recording_rows("inf.csv", set_field(5, "z", "inf")))
    fit("1e308 value", "{W}/huge.csv", recording_rows("huge.csv", set_field(5, "y", "1e308")))
    fit("quaternion of norm 0", "{W}/q0.csv", recording_rows("q0.csv", lambda ls: set_field(2, "qw", "0")(
        set_field(2, "qx", "0")(set_field(2, "qy", "0")(set_field(2, "qz", "0")(ls))))))
    fit("semicolon separated", "{W}/semi.csv", recording_rows("semi.csv", lambda ls: [l.replace(",", ";")
                                                                                      for l in ls]))
    fit("short row", "{W}/short.csv", recording_rows("short.csv", lambda ls: ls[:4] + [ls[4].rsplit(",", 2)[0]]
                                                       + ls[5:]))
    fit("field over 131072 characters", "{W}/bigfield.csv", recording_rows("bigfield.csv", lambda ls: ls[:2] + [
        "1" * 200_000] + ls[3:]))
    fit("NUL byte", "{W}/nul.csv", recording_rows("nul.csv", lambda ls: ls[:2] + [ls[2] + "\0"] + ls[3:]))
    fit("binary garbage", "{W}/garbage.csv", text("garbage.csv", bytes(range(256)) * 64))
    fit("latin-1 text", "{W}/latin.csv", text("latin.csv", (header + "\n" + "é," * 12 + "1\n").encode("latin-1")))
    fit("unclosed quote", "{W}/quote.csv", recording_rows("quote.csv", lambda ls: ls[:2] + ['"' + ls[2]] + ls[3:]))
    fit("duplicate column", "{W}/dup.csv", recording_rows("dup.csv", lambda ls: [l + "," + l.split(",")[0]
                                                                                  for l in ls]))
    fit("joint beyond the limits", "{W}/limit.csv", recording_rows("limit.csv", set_field(3, "q1", "9")))
    fit("time going backwards", "{W}/time.csv", recording_rows("time.csv", lambda ls: [
        l + ("," + ("t" if i == 0 else str(100 - i))) for i, l in enumerate(ls)]))
    fit("one row", "{W}/one.csv", subset("one.csv", [0]))
    fit("a FIFO", "{W}/fifo.csv", fifo("fifo.csv"))
    fit("/dev/zero", "/dev/zero")
    fit("a folder without the Welding layout", "{W}/cell")
    fit("over the size bound (sparse 300 MB)", "{W}/sparse.csv", sparse("sparse.csv", 300 * 2**20))
    fit("positions in metres", "{W}/metres.csv", scaled("metres.csv", 1e-3))
    fit("positions in inches", "{W}/inches.csv", scaled("inches.csv", 1 / 25.4))
    fit("quaternions stored x, y, z, w", "{W}/xyzw.csv", quat_xyzw("xyzw.csv"), method="pi",
        note="quaternion order check")
    out.append(Case("recordings", "diagnose on 7 rows", ["diagnose", "--robot", "R1", "--train", "{W}/seven.csv",
                                                         "--json", "{W}/out/d.json"], ["{W}/out/d.json"],
                    subset("seven.csv", np.arange(7))))
    out.append(Case("recordings", "diagnose on copied rows", ["diagnose", "--robot", "R1", "--train",
                                                              "{W}/same.csv", "--json", "{W}/out/d.json"],
                    ["{W}/out/d.json"], subset("same.csv", np.zeros(63, dtype=int), same=True)))
    out.append(Case("recordings", "rebase on a recording in metres", [
        "rebase", "--model", "{W}/m.yaml", "--data", "{W}/metres.csv", "--out", "{W}/out/r.yaml"],
        ["{W}/out/r.yaml"], scaled("metres.csv", 1e-3)))
    out.append(Case("recordings", "predict joints: a FIFO", ["predict", "--model", "{W}/m.yaml", "--joints",
                                                             "{W}/qfifo.csv", "--out", "{W}/out/p.csv"],
                    ["{W}/out/p.csv"], fifo("qfifo.csv")))
    out.append(Case("recordings", "predict joints: 5 columns", ["predict", "--model", "{W}/m.yaml", "--joints",
                                                                "{W}/q5.csv", "--out", "{W}/out/p.csv"],
                    ["{W}/out/p.csv"], text("q5.csv", "1,2,3,4,5\n")))

    def predict(name: str, model: str, setup=None, note: str = "") -> None:
        out.append(Case("models", name, ["predict", "--model", model, "--joints", "{W}/q.csv", "--out",
                                         "{W}/out/p.csv", "--json", "{W}/out/p.json"],
                        ["{W}/out/p.csv", "{W}/out/p.json"], setup, note))

    other = "model-file number and structure checks"
    predict("missing file", "{W}/nothing.yaml")
    predict("empty file", "{W}/empty.yaml", text("empty.yaml", ""))
    predict("not YAML", "{W}/bad.yaml", text("bad.yaml", "a: [1, 2\n"))
    predict("a YAML list", "{W}/list.yaml", text("list.yaml", "- 1\n- 2\n"))
    predict("binary content", "{W}/bin.yaml", text("bin.yaml", bytes(range(256)) * 8))
    predict("a FIFO", "{W}/fifo.yaml", fifo("fifo.yaml"))
    predict("/dev/zero", "/dev/zero")
    predict("over the size bound (sparse 100 MB)", "{W}/sparse.yaml", sparse("sparse.yaml", 100 * 2**20))
    predict("JSON nested 200,000 deep", "{W}/deep.json", text("deep.json", "[" * 200_000 + "]" * 200_000))
    predict("method unknown", "{W}/meth.yaml", yaml_edit("meth.yaml", lambda d: with_item(d, ["method"], "magic")))
    predict("schema missing", "{W}/schema.yaml", yaml_edit("schema.yaml", lambda d: {k: v for k, v in d.items()
                                                                                    if k != "schema"}))
    predict("nan as text in the geometry", "{W}/nan.yaml", edited("m.yaml", "nan.yaml", lambda t: _first_number(
        t, "nan")), note=other)
    predict("1e308 in the geometry", "{W}/e308.yaml", edited("m.yaml", "e308.yaml", lambda t: _first_number(
        t, "1.0e+308")), note=other)
    predict("a string in the geometry", "{W}/str.yaml", edited("m.yaml", "str.yaml", lambda t: _first_number(
        t, "'abc'")))
    predict("billion laughs", "{W}/laughs.yaml", edited("m.yaml", "laughs.yaml", lambda t: t.replace(
        "\ngeometry:\n", "\n" + _laughs() + "geometry:\n", 1)), note=other)
    predict("a 2-million-element list", "{W}/long.yaml", edited("m.yaml", "long.yaml", lambda t: t.replace(
        "\n  P:\n", "\n  P: [" + "0.0, " * 2_000_000 + "0.0]\n  P_was:\n", 1)), note=other)

    def plan_cmd(cmd: str, name: str, plan: str, setup=None, note: str = "", marks: str = "") -> None:
        argv = {"export-targets": ["export-targets", "--plan", plan, "--out", "{W}/out/t.csv", "--json",
                                   "{W}/out/t.json"],
                "preview": ["preview", "--plan", plan, "--html", "{W}/out/p.html", "--json", "{W}/out/p.json"],
                "collect": ["collect", "--robot", "R1", "--plan", plan, "--session", "{W}/out/s", "--sim",
                            "--dry-run"]}[cmd]
        outputs = [a for a in argv if a.startswith("{W}/out/")]
        out.append(Case("plans", f"{cmd}: {name}", argv, outputs, setup, note, marks if cmd == "preview" else ""))

    safety = "plan safety (app.collection.plan_safety)"
    for cmd in ("export-targets", "preview"):
        plan_cmd(cmd, "missing file", "{W}/nothing.json")
        plan_cmd(cmd, "not JSON", "{W}/bad.json", text("bad.json", "{"))
        plan_cmd(cmd, "binary", "{W}/bin.json", text("bin.json", bytes(range(256)) * 8))
        plan_cmd(cmd, "a FIFO", "{W}/fifo.json", fifo("fifo.json"))
        plan_cmd(cmd, "/dev/zero", "/dev/zero")
        plan_cmd(cmd, "480 MB (sparse)", "{W}/sparse.json", sparse("sparse.json", 480 * 2**20))
        plan_cmd(cmd, "nested 200,000 deep", "{W}/deep.json", text("deep.json", '{"schema": "cellcal.plan/1", '
                 '"kind": "dual", "waypoints": ' + "[" * 200_000 + "]" * 200_000 + "}"))
        plan_cmd(cmd, "200,000 empty waypoints", "{W}/many.json", text("many.json", json.dumps(
            {"schema": "cellcal.plan/1", "kind": "dual", "waypoints": [{}] * 200_000})))
        plan_cmd(cmd, "wrong schema", "{W}/schema.json", json_edit("dual.json", "schema.json",
                                                                  lambda d: with_item(d, ["schema"], "x")))
        plan_cmd(cmd, "unknown kind", "{W}/kind.json", json_edit("dual.json", "kind.json",
                                                                lambda d: with_item(d, ["kind"], "triple")))
        plan_cmd(cmd, "a string angle", "{W}/str.json", json_edit("dual.json", "str.json", lambda d: with_item(
            d, ["waypoints", 1, "R1", 2], "0.1")))
        plan_cmd(cmd, "R2 26 mm below the floor", "{W}/floor.json", json_edit("dual.json", "floor.json", lambda d: {
            **d, "waypoints": [{**wp, "R2": [0, 1.2, -0.5, 0, 0, 0]} for wp in d["waypoints"]]}), note=safety,
            marks="UNSAFE waypoint")
        plan_cmd(cmd, "residual 50 mm marked converged", "{W}/resid.json", json_edit(
            "dual.json", "resid.json", lambda d: with_item(d, ["waypoints", 2, "residual_mm"], 50.0)), note=safety,
            marks="UNSAFE waypoint")
    plan_cmd("collect", "a collection plan with a string angle", "{W}/cstr.json", json_edit(
        "plan.json", "cstr.json", lambda d: with_item(d, ["targets", 0, "q_rad", 1], "x")))
    plan_cmd("collect", "a FIFO", "{W}/fifo.json", fifo("fifo.json"))
    out.append(Case("plans", "plan-dual: binary --path file", ["plan-dual", "--path", "{W}/bin.csv", "--out",
                                                               "{W}/out/d.json"], ["{W}/out/d.json"],
                    text("bin.csv", bytes(range(256)) * 8)))
    out.append(Case("plans", "plan-dual: --path a FIFO", ["plan-dual", "--path", "{W}/pfifo.csv", "--out",
                                                          "{W}/out/d.json"], ["{W}/out/d.json"], fifo("pfifo.csv")))
    out.append(Case("plans", "plan-dual: --path nested deep", ["plan-dual", "--path", "{W}/pdeep.json", "--out",
                                                               "{W}/out/d.json"], ["{W}/out/d.json"],
                    text("pdeep.json", "[" * 200_000 + "]" * 200_000)))

    def cell(name: str, cell_file: str, setup=None) -> None:
        out.append(Case("cells", name, ["plan", "--design", "grid", "--cell", cell_file, "--robot", "R1", "--q2-step",
                                        "60", "--q3-step", "60", "--out", "{W}/out/plan.json"], ["{W}/out/plan.json"],
                        setup))

    cell("missing file", "{W}/cell/nothing.yaml")
    cell("empty file", "{W}/cell/empty.yaml", text("cell/empty.yaml", ""))
    cell("not YAML", "{W}/cell/bad.yaml", text("cell/bad.yaml", "robots: [\n"))
    cell("binary", "{W}/cell/bin.yaml", text("cell/bin.yaml", bytes(range(256)) * 8))
    cell("a FIFO", "{W}/cell/fifo.yaml", fifo("cell/fifo.yaml"))
    cell("/dev/zero", "/dev/zero")
    cell("over the size bound (sparse 100 MB)", "{W}/cell/sparse.yaml", sparse("cell/sparse.yaml", 100 * 2**20))
    cell("robots missing", "{W}/cell/norobots.yaml", cell_edit("norobots.yaml", lambda t: t.replace("robots:",
                                                                                                  "robits:", 1)))
    cell("robot file missing", "{W}/cell/norobot.yaml", cell_edit("norobot.yaml", lambda t: t.replace(
        "robots/MA2010.yaml", "robots/nothing.yaml")))
    cell("robot file a FIFO", "{W}/cell/robotfifo.yaml", lambda w: (fifo("cell/robots/fifo.yaml")(w), cell_edit(
        "robotfifo.yaml", lambda t: t.replace("robots/MA2010.yaml", "robots/fifo.yaml"))(w)))
    cell("T_cell_base not 4x4", "{W}/cell/T.yaml", cell_edit("T.yaml", lambda t: t.replace(
        "      - [0, 0, 0, 1]\n  R2:", "  R2:", 1)))
    cell("T_cell_base with nan", "{W}/cell/Tnan.yaml", cell_edit("Tnan.yaml", lambda t: t.replace(
        "2703.649529", "nan", 1)))
    cell("unknown key", "{W}/cell/key.yaml", cell_edit("key.yaml", lambda t: t + "\nbogus: 1\n"))

    def fit_out(name: str, out_path: str, setup=None, extra: list[str] | None = None) -> None:
        out.append(Case("outputs", name, ["fit", "--robot", "R1", "--train", "{W}/train.csv", "--method", "nls1",
                                          "--out", out_path, *(extra or [])], [], setup))

    fit_out("a folder", "{W}/out")
    fit_out("/dev/full", "/dev/full")
    fit_out("a symlink", "{W}/link.yaml", lambda w: (w / "link.yaml").exists() or os.symlink(w / "target.yaml",
                                                                                              w / "link.yaml"))
    fit_out("under a file", "{W}/train.csv/m.yaml")
    fit_out("empty path", "")
    fit_out("a FIFO", "{W}/ofifo", fifo("ofifo"))
    fit_out("the training recording itself", "{W}/train.csv")
    fit_out("--json the same as --out", "{W}/out/same.yaml", extra=["--json", "{W}/out/same.yaml"])
    out.append(Case("outputs", "export --out the session database", [
        "export", "--session", "{W}/session", "--out", "{W}/session/session.sqlite"], []))
    out.append(Case("outputs", "evaluate --report a file", ["evaluate", "--model", "{W}/m.yaml", "--test",
                                                            "{W}/train.csv", "--report", "{W}/train.csv"], []))

    def opt(name: str, argv: list[str]) -> None:
        out.append(Case("options", name, argv, [a for a in argv if a.startswith("{W}/out/")]))

    train = ["--robot", "R1", "--train", "{W}/train.csv"]
    opt("unknown method", ["fit", *train, "--method", "magic", "--out", "{W}/out/m.yaml"])
    opt("mistyped option", ["fit", *train, "--methd", "nls1", "--out", "{W}/out/m.yaml"])
    opt("--a nan", ["fit", *train, "--method", "nls1", "--a", "nan", "--out", "{W}/out/m.yaml"])
    opt("--a -1", ["fit", *train, "--method", "nls1", "--a", "-1", "--out", "{W}/out/m.yaml"])
    opt("unknown robot", ["fit", "--robot", "R9", "--train", "{W}/train.csv", "--method", "nls1", "--out",
                          "{W}/out/m.yaml"])
    opt("--tolerance-mm nan", ["evaluate", "--model", "{W}/m.yaml", "--test", "{W}/train.csv", "--tolerance-mm",
                               "nan", "--report", "{W}/out/rep"])
    opt("plan --validation 1e9", ["plan", "--robot", "R1", "--validation", "1000000000", "--out", "{W}/out/p.json"])
    opt("plan --q2-step 0", ["plan", "--design", "grid", "--robot", "R1", "--q2-step", "0", "--out", "{W}/out/p.json"])
    opt("plan --seed -1", ["plan", "--robot", "R1", "--seed", "-1", "--out", "{W}/out/p.json"])
    opt("plan-dual sweep:abc", ["plan-dual", "--path", "sweep:abc", "--out", "{W}/out/d.json"])
    opt("plan-dual sweep:1000000000", ["plan-dual", "--path", "sweep:1000000000", "--out", "{W}/out/d.json"])
    opt("rebase --tolerance 2", ["rebase", "--model", "{W}/m.yaml", "--data", "{W}/train.csv", "--tolerance", "2",
                                 "--out", "{W}/out/r.yaml"])
    opt("export --kinds bogus", ["export", "--session", "{W}/session", "--kinds", "bogus", "--out", "{W}/out/e.csv"])
    opt("export --out without .csv", ["export", "--session", "{W}/session", "--out", "{W}/out/e.txt"])
    opt("compensate-job --max-joint-change-deg -5", ["compensate-job", "--model", "{W}/m.yaml", "--job",
                                                     "{W}/IN.JBI", "--max-joint-change-deg", "-5", "--out",
                                                     "{W}/out/OUT.JBI"])
    opt("--cell given twice, different", ["--cell", "{W}/cell/cell.yaml", "plan", "--cell", "{W}/train.csv",
                                          "--robot", "R1", "--out", "{W}/out/p.json"])

    def export(name: str, session: str, setup=None) -> None:
        out.append(Case("sessions", name, ["export", "--session", session, "--out", "{W}/out/e.csv", "--json",
                                           "{W}/out/e.json"], ["{W}/out/e.csv", "{W}/out/e.json"], setup))

    export("missing folder", "{W}/nosession")
    export("empty folder", "{W}/emptyfolder", lambda w: (w / "emptyfolder").mkdir(exist_ok=True))
    export("empty database file", "{W}/s_empty", session_file("s_empty", b""))
    export("garbage database file", "{W}/s_garbage", session_file("s_garbage", bytes(range(256)) * 64))
    export("database a FIFO", "{W}/s_fifo", session_file("s_fifo", None))
    for i, (label, sql) in enumerate([
            ("text in x", "UPDATE samples SET x = 'abc' WHERE target_index = 1"),
            ("NULL in q3", "UPDATE samples SET q3 = NULL WHERE target_index = 0"),
            ("inf in qw", "UPDATE samples SET qw = 9e999 WHERE target_index = 2"),
            ("quaternion of norm 3", "UPDATE samples SET qw = 3.0 WHERE target_index = 1"),
            ("text cluster", "UPDATE samples SET cluster = 'a' WHERE target_index = 0"),
            ("info not JSON", "UPDATE meta SET value = '{not json' WHERE key = 'info'"),
            ("info a list", "UPDATE meta SET value = '[1, 2]' WHERE key = 'info'"),
            ("plan not JSON", "UPDATE meta SET value = 'nope' WHERE key = 'plan'"),
            ("plan of another schema", "UPDATE meta SET value = '{\"schema\": 3}' WHERE key = 'plan'"),
            ("plan nested deep", "UPDATE meta SET value = '" + "[" * 100_000 + "]" * 100_000 + "' WHERE key = 'plan'"),
            ("samples table dropped", "DROP TABLE samples"),
            ("a row of another robot", "UPDATE samples SET robot = 'R2' WHERE target_index = 0")]):
        export(label, f"{{W}}/s{i}", session_sql(f"s{i}", sql))

    def job(name: str, job_file: str, setup=None) -> None:
        out.append(Case("jobs", name, ["compensate-job", "--model", "{W}/m.yaml", "--job", job_file, "--out",
                                       "{W}/out/OUT.JBI", "--json", "{W}/out/j.json"],
                        ["{W}/out/OUT.JBI", "{W}/out/j.json"], setup))

    job("missing file", "{W}/nothing.JBI")
    job("empty file", "{W}/empty.JBI", text("empty.JBI", ""))
    job("binary", "{W}/bin.JBI", text("bin.JBI", bytes(range(256)) * 8))
    job("a FIFO", "{W}/fifo.JBI", fifo("fifo.JBI"))
    job("/dev/zero", "/dev/zero")
    job("over the size bound (sparse 100 MB)", "{W}/sparse.JBI", sparse("sparse.JBI", 100 * 2**20))
    job("no /JOB line", "{W}/nojob.JBI", lambda w: (w / "nojob.JBI").write_bytes((w / "IN.JBI").read_bytes()
                                                                                 .replace(b"/JOB", b"JOB", 1)))
    job("NPOS disagreeing", "{W}/npos.JBI", lambda w: (w / "npos.JBI").write_bytes((w / "IN.JBI").read_bytes()
                                                                                   .replace(b"NPOS 3", b"NPOS 9")))
    job("pulse not a number", "{W}/pulse.JBI", lambda w: (w / "pulse.JBI").write_bytes(
        (w / "IN.JBI").read_bytes().replace(b"C00001=", b"C00001=x", 1)))
    job("a folder", "{W}/cell")
    return out


def _first_number(yaml_text: str, value: str) -> str:
    """``yaml_text`` with the first number of the geometry's base link ``P[0]`` replaced by ``value`` (as text: a
    plain ``nan`` is what PyYAML reads as a string)."""
    import re

    start = yaml_text.index("\n  P:\n")
    head, tail = yaml_text[:start], yaml_text[start:]
    return head + re.sub(r"(?<=\[)-?\d+\.\d+(e[-+]?\d+)?", value, tail, count=1)


def _laughs() -> str:
    """Top-level keys whose last is 9**10 'lol's by aliases (a few hundred bytes)."""
    lines = ["lol_a: &a [lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    for i, name in enumerate("bcdefghij"):
        prev = "abcdefghij"[i]
        lines.append(f"lol_{name}: &{name} [{', '.join(['*' + prev] * 9)}]")
    return "\n".join(lines) + "\n"


# -- running and judging -----------------------------------------------------------------------------------------------

def _digest(path: Path) -> str | None:
    try:
        if path.is_file():
            return hashlib.sha256(path.read_bytes()).hexdigest()
        if path.exists():
            return "exists"
    except OSError:
        return "unreadable"
    return None


def replay(case: Case, w: Path, timeout_s: float) -> Outcome:
    def fill(s: str) -> str:
        return s.replace("{W}", str(w))

    shutil.rmtree(w / "out", ignore_errors=True)
    (w / "out").mkdir()
    if case.setup is not None:
        case.setup(w)
    argv = [fill(a) for a in case.argv]
    outputs = [Path(fill(o)) for o in case.outputs]
    before = {o: _digest(o) for o in outputs}
    start = time.perf_counter()
    try:
        proc = run(argv, timeout_s)
        code, err = proc.returncode, proc.stderr
    except subprocess.TimeoutExpired as e:
        code, err = None, (e.stderr.decode(errors="replace") if isinstance(e.stderr, bytes) else e.stderr or "")
    seconds = time.perf_counter() - start
    wrote = [str(o) for o in outputs if code not in (0, None) and _digest(o) != before[o]]
    lines = [line for line in err.strip().splitlines() if line.strip() and not line.startswith("warning:")]
    if code is None:
        verdict = "hang"
    elif "Traceback (most recent call last)" in err or code not in (0, 2, 130):
        verdict = "traceback"
    elif wrote:
        verdict = "wrote on failure"
    elif code == 0 and case.marks and case.marks in err:
        verdict = "marked"
    elif code == 0:
        verdict = "accepted"
    elif len(lines) == 1:
        verdict = "clean"
    else:
        verdict = "unclear"
    return Outcome(case.family, case.name, verdict, code, seconds, err.strip().splitlines()[-1] if err.strip() else "",
                   wrote)


VERDICTS = ("clean", "marked", "accepted", "traceback", "hang", "wrote on failure", "unclear")


def table(outcomes: list[Outcome]) -> str:
    head = f"{'family':<12} {'tried':>5} {'clean exit 2':>12} {'marked':>6} {'accepted':>8} {'traceback':>9} {'hang':>4} " \
           f"{'wrote on failure':>16} {'unclear':>7}"
    rows = [head, "-" * len(head)]
    for fam in [*FAMILIES, "total"]:
        sel = [o for o in outcomes if fam == "total" or o.family == fam]
        if not sel:
            continue
        n = {v: sum(o.verdict == v for o in sel) for v in VERDICTS}
        rows.append(f"{fam:<12} {len(sel):>5} {n['clean']:>12} {n['marked']:>6} {n['accepted']:>8} {n['traceback']:>9} "
                    f"{n['hang']:>4} {n['wrote on failure']:>16} {n['unclear']:>7}")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", help="write every case's outcome as JSON")
    ap.add_argument("--families", default=",".join(FAMILIES), help="comma-separated families to replay")
    ap.add_argument("--case", action="append", help="a case to replay ('family: name' or 'name', as --list prints "
                                                    "them; repeat for more); default: every case of the families")
    ap.add_argument("--timeout-s", type=float, default=30.0, help="per case (default %(default)g)")
    ap.add_argument("--list", action="store_true", help="list the cases and stop")
    args = ap.parse_args(argv)
    families = args.families.split(",")
    bad = [f for f in families if f not in FAMILIES]
    if bad:
        ap.error(f"unknown family {bad[0]}; valid: {', '.join(FAMILIES)}")
    chosen = [c for c in cases() if c.family in families]
    if args.case:
        names = set(args.case)
        chosen = [c for c in chosen if c.name in names or f"{c.family}: {c.name}" in names]
    if args.list:
        for c in chosen:
            print(f"{c.family}: {c.name}{'  [' + c.note + ']' if c.note else ''}")
        return 0
    outcomes = []
    with tempfile.TemporaryDirectory(prefix="cellcal-replay-") as tmp:
        w = Path(tmp)
        start = time.perf_counter()
        make_base(w)
        for case in chosen:
            o = replay(case, w, args.timeout_s)
            outcomes.append(o)
            print(f"  {o.verdict:<16} {o.seconds:5.1f} s  {o.family}: {o.name}", file=sys.stderr, flush=True)
        total_s = time.perf_counter() - start
    print(table(outcomes))
    print(f"({len(outcomes)} cases in {total_s:.0f} s, timeout {args.timeout_s:g} s each)")
    notes = {(c.family, c.name): c.note for c in chosen}
    for o in outcomes:
        if o.verdict != "clean":
            note = notes.get((o.family, o.name))
            print(f"{o.verdict}: {o.family}: {o.name} (exit {o.code}){' [' + note + ']' if note else ''}: "
                  f"{o.stderr[:300]}")
    if args.json:
        Path(args.json).write_text(json.dumps([{**o.__dict__, "note": notes.get((o.family, o.name), "")}
                                               for o in outcomes], indent=1))
    failed = any(o.verdict in ("traceback", "hang", "wrote on failure") for o in outcomes)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
