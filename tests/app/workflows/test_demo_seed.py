"""``cellcal demo --seed`` is reproducible: the same seed gives the same figures, another seed other ones, and
``--time-scale`` changes how long the demo takes, never what it measures.

Short demos (coarse anchor grid, few validation poses, two methods) through the CLI's ``--json``. Wall-clock
durations (and the time scale itself) are the only figures allowed to differ between runs of one seed.
"""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import pytest

from app.cli.commands import main

SHORT = ["--anchor-step", "90", "--validation", "3", "--methods", "nominal,nls1", "--no-progress"]
#: The time scale of runs "a" and "c" (run "b" keeps the default, 20): 10 times faster collections.
FAST = 200.0


def figures(data: object) -> object:
    """``data`` without wall-clock durations and file paths (every ``*seconds`` key, ``summary``, ``report``)."""
    if isinstance(data, dict):
        return {k: figures(v) for k, v in data.items()
                if not k.endswith("seconds") and k not in ("summary", "report")}
    if isinstance(data, list):
        return [figures(v) for v in data]
    return data


def without_time_scale(summary: dict) -> dict:
    """``summary`` without ``config.time_scale`` (the one setting runs "a" and "b" differ in)."""
    return {**summary, "config": {k: v for k, v in summary["config"].items() if k != "time_scale"}}


def demo(tmp: Path, name: str, seed: int, *extra: str) -> tuple[dict, Path, str]:
    """(the --json file, the output folder, what the demo printed)."""
    out, printed = tmp / name, io.StringIO()
    with contextlib.redirect_stdout(printed):
        code = main(["demo", "--out", str(out), "--seed", str(seed), "--json", str(tmp / f"{name}.json"), *SHORT,
                     *extra])
    assert code == 0, printed.getvalue()
    return json.loads((tmp / f"{name}.json").read_text()), out, printed.getvalue()


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Seed 0 at the fast time scale ("a") and at the default one ("b"), seed 1 at the fast one ("c")."""
    tmp = tmp_path_factory.mktemp("demo_seed")
    fast = ("--time-scale", f"{FAST:g}")
    return {name: demo(tmp, name, seed, *extra) for name, seed, extra in (("a", 0, fast), ("b", 0, ()),
                                                                          ("c", 1, fast))}


def test_the_same_seed_gives_the_same_figures_and_recordings(runs):
    """At another time scale too: the stepped clock makes what is measured a function of simulated time only."""
    (a, out_a, _), (b, out_b, _) = runs["a"], runs["b"]
    assert (a["config"]["time_scale"], b["config"]["time_scale"]) == (FAST, 20.0)
    assert figures(without_time_scale(a)) == figures(without_time_scale(b))
    for robot in a["robots"]:
        for name in ("train.csv", "cpa.csv", "test.csv"):
            assert (out_a / robot / name).read_bytes() == (out_b / robot / name).read_bytes(), f"{robot}/{name}"


def test_another_seed_gives_other_figures(runs):
    (a, _, _), (c, _, _) = runs["a"], runs["c"]
    assert a["config"]["seed"] == 0 and c["config"]["seed"] == 1
    for robot in a["robots"]:
        assert a["robots"][robot]["methods"]["nls1"]["test"] != c["robots"][robot]["methods"]["nls1"]["test"]


def test_the_json_holds_what_the_demo_prints(runs):
    a, _, printed = runs["a"]
    rows = {tuple(line.split()[:2]): line.split()[2:] for line in printed.splitlines()[1:]
            if len(line.split()) == 5 and "skipped:" not in line}
    for robot, r in a["robots"].items():
        assert r["samples"] == r["train_samples"] + r["cpa_samples"] + r["test_samples"]
        for method, v in r["methods"].items():
            p, o = v["test"]["position_mm"], v["test"]["orientation_deg"]
            assert rows[(robot, method)] == [f"{p['mean']:.3f}", f"{p['max']:.3f}", f"{o['mean']:.4f}"]
    assert set(rows) == {(r, m) for r in a["robots"] for m in ("nominal", "nls1")}
    for robot, r in a["robots"].items():
        assert r["recommended"] in r["methods"]
        assert f"{robot:<5} recommended (chosen on clusters held out from training): {r['recommended']}" in printed
    assert f"{a['mocap_frames_received']} mocap frames" in printed
    assert f"report: {a['report']}" in printed


@pytest.mark.parametrize("bad,fragment", [(["--anchor-step", "0"], "--anchor-step must be in [0.5, 90] deg"),
                                          (["--validation", "0"], "--validation must be at least 1"),
                                          (["--time-scale", "0"], "--time-scale must be in (0, 1000]"),
                                          (["--time-scale", "nan"], "--time-scale must be in (0, 1000]"),
                                          (["--time-scale", "inf"], "--time-scale must be in (0, 1000]"),
                                          (["--methods", "nls1,magic"], "unknown method 'magic'")])
def test_bad_demo_options_exit_2_and_write_nothing(tmp_path, capsys, bad, fragment):
    from tests.conftest import assert_bad_input

    assert_bad_input(capsys, ["demo", "--out", str(tmp_path / "out"), "--json", str(tmp_path / "d.json"), *bad],
                     fragment)
    assert list(tmp_path.iterdir()) == []
