"""Progress bars: a log line during a bar lands on a line of its own; bars only on a terminal, never with --quiet."""

import io
import logging

import pytest

from app import progress
from tests.conftest import backlash_case


class FakeTTY(io.StringIO):
    """A terminal as far as tqdm and the policy can tell."""

    def isatty(self) -> bool:
        return True


@pytest.fixture
def tty_bars():
    """Bars on (as on a terminal) for the test, the policy restored afterwards."""
    before = progress.enabled()
    progress.configure(stream=FakeTTY())
    yield
    progress._state["enabled"] = before


def _run_bar_with_a_warning(stream: io.StringIO, handler: logging.Handler) -> str:
    log = logging.getLogger("cellcal.test.progress")
    log.propagate, log.handlers = False, [handler]
    try:
        with progress.bar(range(10), file=stream, desc="work", mininterval=0, miniters=1) as b:
            for i in b:
                if i == 5:
                    log.warning("a warning mid-bar")
    finally:
        log.handlers, log.propagate = [], True
    return stream.getvalue()


def _lines(text: str) -> list[str]:
    """What a terminal shows: each newline-separated line after its last carriage return."""
    return [line.rsplit("\r", 1)[-1] for line in text.split("\n")]


def test_a_warning_logged_during_a_bar_ends_up_on_its_own_line(tty_bars):
    stream = FakeTTY()
    text = _run_bar_with_a_warning(stream, progress.TqdmLoggingHandler(stream))
    assert "a warning mid-bar" in _lines(text)
    assert "work: 100%" in _lines(text)[-2]  # the bar redrawn after it and finished below it


def test_a_plain_stream_handler_breaks_the_bar_mid_line(tty_bars):
    """The failure the handler prevents: without it the warning is glued onto the bar's line."""
    stream = FakeTTY()
    text = _run_bar_with_a_warning(stream, logging.StreamHandler(stream))
    assert "a warning mid-bar" not in _lines(text)
    assert any(line.startswith("work:") and line.endswith("a warning mid-bar") for line in _lines(text))


def test_bars_only_on_a_terminal_and_never_with_quiet():
    before = progress.enabled()
    try:
        assert progress.configure(stream=FakeTTY())
        assert not progress.configure(quiet=True, stream=FakeTTY())
        assert not progress.configure(stream=io.StringIO())
        stream = io.StringIO()
        for _ in progress.bar(range(3), file=stream):
            pass
        assert stream.getvalue() == ""
    finally:
        progress._state["enabled"] = before


def test_the_cli_installs_the_handler_and_takes_quiet(tmp_path):
    from app.cli.commands import main

    assert main(["-q", "plan", "--robot", "R1", "--out", str(tmp_path / "p.json"), "--design", "grid", "--q2-step", "50",
                 "--q3-step", "50"]) == 0
    assert not progress.enabled()
    assert any(isinstance(h, progress.TqdmLoggingHandler) for h in logging.getLogger().handlers)


def test_diagnose_reports_its_steps_in_order_and_the_result_is_unchanged():
    from calibration.diagnosis import diagnose
    from calibration.diagnosis.core import DIAGNOSE_STEPS

    nominal, gravity, fit, ho = backlash_case()
    steps: list[str] = []
    plain = diagnose("R1", nominal, fit, ho, gravity=gravity)
    reported = diagnose("R1", nominal, fit, ho, gravity=gravity, progress=steps.append)
    assert steps == list(DIAGNOSE_STEPS)
    assert reported.verdict == plain.verdict and reported.to_json() == plain.to_json()


def test_the_planner_reports_every_waypoint():
    pytest.importorskip("casadi")
    import numpy as np

    from app.dual.paths import Q_REF_DEG, read_path, relative_pose
    from app.dual.planner import DualPlanner, PlannerOptions
    from cell_config import load_cell

    planner = DualPlanner(load_cell(), options=PlannerOptions(compile="off"))
    path = read_path("sweep:4", planner)
    q0 = np.radians(Q_REF_DEG)
    seen = []
    plan = planner.plan(path, relative_pose(planner, q0), q0, on_waypoint=seen.append)
    assert seen == list(plan.waypoints) and len(seen) == 4
