"""prove_discovery's options that cut its work: an unknown --cases name is refused, naming it, and --no-table with
--no-power runs nothing and says so."""

import pytest

from scripts.studies.prove_discovery import ISSUE13, main


def test_an_unknown_case_is_refused_with_its_name_and_the_valid_ones(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--quick", "--only", "issue13", "--cases", f"{next(iter(ISSUE13))},bogus"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "unknown case 'bogus'" in err and all(name in err for name in ISSUE13)


def test_no_table_and_no_power_run_no_case(tmp_path, capsys):
    assert main(["--quick", "--only", "issue13", "--no-table", "--no-power", "--out", str(tmp_path)]) == 0
    assert "0 of 0 cases right" in capsys.readouterr().out
