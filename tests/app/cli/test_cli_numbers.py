"""Bounds given on the command line are finite numbers > 0, refused by the parser in one line naming the option:
``nan`` passes every ``<`` test and ``inf`` every ``>`` test, so such a bound was silently no bound, or reached
numpy as a traceback."""

import pytest

from app.cli.commands import main

CASES = [
    (["register", "--robot", "R1", "--sim", "--dry-run"], "--sweep"),  # nan: numpy's uniform raised OverflowError
    (["compensate-job", "--model", "m.yaml", "--job", "J.JBI", "--out", "O.JBI"],
     "--max-joint-change-deg"),  # nan: no compensation was ever too large, the check was off
    (["mocap-bridge"], "--frame-timeout"),  # nan: Motive never counted as gone, the bridge never reconnected
]


@pytest.mark.parametrize("value", ["nan", "inf", "-1", "0"])
@pytest.mark.parametrize("argv, option", CASES, ids=[f"{a[0]} {o}" for a, o in CASES])
def test_a_non_finite_or_non_positive_bound_is_one_line_naming_the_option(argv, option, value, tmp_path,
                                                                          monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as stop:  # argparse's exit, before the command runs
        main([*argv, f"{option}={value}"])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"argument {option}: expected a finite number > 0, got {value}" in err[0], err
    assert list(tmp_path.iterdir()) == []
