"""``cellcal demo`` stopped by Ctrl-C says what it left in its output folder and what a re-run does with it."""

from __future__ import annotations

import re

from app.cli.commands import main


def test_ctrl_c_during_demo_names_what_was_left_and_that_a_re_run_replaces_it(tmp_path, capsys, monkeypatch):
    # it said only "cellcal demo: stopped", leaving R1/plan.json and R1/session/ behind without a word
    import app.workflows.demo

    def interrupted(sim, safety, robot, plan, session_dir, *args, **kwargs):
        session_dir.mkdir(parents=True)  # a collection stopped part-way: its session folder exists
        raise KeyboardInterrupt

    monkeypatch.setattr(app.workflows.demo, "collect_arm", interrupted)
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--anchor-step", "90", "--validation", "1", "--methods", "nominal",
                 "--no-progress"]) == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert re.fullmatch(rf"cellcal demo: stopped \(left in {re.escape(str(out))}: R1/plan\.json, R1/session/; nothing "
                        rf"was deleted: a re-run of cellcal demo --out {re.escape(str(out))} removes these and starts "
                        r"over\)", err[0]), err[0]
    assert sorted(p.name for p in (out / "R1").iterdir()) == ["plan.json", "session"]  # nothing removed
