"""Seeds and pose counts on the command line are integers >= 0: a negative --seed reached numpy's generator as a
traceback (exit 1) from plan, demo, collect --sim, ...; plan --validation -5 said "cellcal plan: plan: validation"."""

import argparse

import pytest

from app.cli.commands import build_parser, main


def _seed_options() -> list[tuple[str, str]]:
    """(command, option) of every seed option of every subcommand, and plan's validation count."""
    root = build_parser()
    subs = next(a for a in root._actions if isinstance(a, argparse._SubParsersAction))
    out = [(name, opt) for name, p in subs.choices.items() for a in p._actions for opt in a.option_strings
           if opt.startswith("--") and a.dest in ("seed", "validation_seed")]
    return out + [("plan", "--validation")]


SEED_OPTIONS = _seed_options()


def test_the_walk_finds_the_seed_options():
    assert {("plan", "--seed"), ("demo", "--seed"), ("collect", "--seed"), ("fake-motive", "--seed"),
            ("recalibrate", "--validation-seed")} <= set(SEED_OPTIONS)


def refused_by_the_parser(argv: list[str], message: str, folder, capsys) -> None:
    """``main(argv)`` exits 2 from argparse, before the command runs, with one stderr line holding ``message``, and
    writes nothing into ``folder`` (the working folder)."""
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
    assert list(folder.iterdir()) == []


@pytest.mark.parametrize("command, option", SEED_OPTIONS, ids=[f"{c} {o}" for c, o in SEED_OPTIONS])
def test_a_negative_seed_or_count_is_one_line_naming_the_option(command, option, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    refused_by_the_parser([command, option, "-1"], f"argument {option}: expected an integer >= 0, got -1", tmp_path,
                          capsys)


def test_plan_takes_seed_zero_and_a_validation_count(tmp_path):
    out = tmp_path / "plan.json"
    assert main(["plan", "--robot", "R1", "--out", str(out), "--design", "grid", "--q2-step", "30", "--q3-step", "30", "--seed", "0",
                 "--validation", "2"]) == 0
    assert out.exists()


@pytest.mark.parametrize("command", ["plan", "recalibrate", "demo"])
def test_a_validation_count_past_ten_thousand_is_refused_before_anything_runs(command, tmp_path, monkeypatch, capsys):
    """plan --validation 100000000 ran for minutes building a plan of poses nobody could measure."""
    monkeypatch.chdir(tmp_path)
    refused_by_the_parser([command, "--validation", "100000000"],
                          "argument --validation: expected at most 10000 validation poses", tmp_path, capsys)
    from app.cli.common import validation_count

    assert validation_count("10000") == 10000


@pytest.mark.parametrize("command, option, value, expected", [
    ("fake-controller", "--servo-on-delay", "nan", "expected a finite number >= 0, got nan"),
    ("fake-controller", "--servo-on-delay", "-1", "expected a finite number >= 0, got -1"),
    ("fake-motive", "--rate", "0", "expected a finite number > 0, got 0"),
    ("fake-motive", "--rate", "nan", "expected a finite number > 0, got nan"),
    ("fake-motive", "--noise-pos-mm", "inf", "expected a finite number >= 0, got inf"),
    ("fake-motive", "--compliance-mm", "-0.5", "expected a finite number >= 0, got -0.5"),
])
def test_the_fake_peers_numbers_are_checked_by_the_parser(command, option, value, expected, tmp_path, monkeypatch,
                                                          capsys):
    """fake-controller --servo-on-delay nan was accepted (new-user run), and fake-motive --rate 0 was refused by the
    fake Motive as 'rate_hz', a name the command line does not have."""
    monkeypatch.chdir(tmp_path)
    refused_by_the_parser([command, f"{option}={value}"], f"argument {option}: {expected}", tmp_path, capsys)


@pytest.mark.parametrize("command", ["plan", "select"])
def test_noise_mm_is_a_finite_positive_number_for_every_design(command, tmp_path, monkeypatch, capsys):
    """plan --noise-mm nan was accepted on a grid plan, which does not use it (checked only for --design optimal)."""
    monkeypatch.chdir(tmp_path)
    refused_by_the_parser([command, "--noise-mm", "nan"], "argument --noise-mm: expected a finite number > 0, got nan",
                          tmp_path, capsys)
