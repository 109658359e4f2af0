"""``cellcal init-cell DIR``: an editable cell folder that loads as written and is the cell the commands use;
nothing is overwritten; and the whole path of a new user's cell, init-cell -> plan -> collect --sim -> fit ->
evaluate --report, on that folder."""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.cli.commands import main
from cell_config import load_cell
from tests.conftest import assert_bad_input


def test_init_cell_writes_a_folder_that_loads_as_written_and_is_the_cell_used(tmp_path, capsys):
    folder = tmp_path / "mycell"
    assert main(["init-cell", str(folder), "--json", str(tmp_path / "i.json")]) == 0
    assert f"cellcal --cell {folder / 'cell.yaml'} plan" in capsys.readouterr().out
    files = json.loads((tmp_path / "i.json").read_text())["files"]
    assert set(files) == {"cell.yaml", "robots/MA2010.yaml", "robots/MA1440.yaml", "tools/weldgun_marker.yaml",
                          "tools/mti_marker.yaml"}
    packaged, mine = load_cell(), load_cell(folder / "cell.yaml")
    for name in ("R1", "R2"):
        np.testing.assert_array_equal(mine.robot(name).T_cell_base, packaged.robot(name).T_cell_base)
        np.testing.assert_array_equal(mine.robot(name).robot.P, packaged.robot(name).robot.P)
    for rel in files:  # each file names its units
        assert "Units:" in (folder / rel).read_text().split("\n", 4)[-1] or "Units:" in (folder / rel).read_text()
    # the folder is the cell the commands read: an edit shows
    robot = folder / "robots" / "MA2010.yaml"
    robot.write_text(robot.read_text().replace("upper: [180, 155, 160, 150, 90, 210]",
                                               "upper: [170, 155, 160, 150, 90, 210]"))
    assert np.degrees(load_cell(folder / "cell.yaml").robot("R1").robot.upper_rad[0]) == pytest.approx(170)


def test_init_cell_never_overwrites(tmp_path, capsys):
    folder = tmp_path / "mycell"
    (folder / "tools").mkdir(parents=True)
    (folder / "tools" / "mti_marker.yaml").write_text("mine\n")
    assert_bad_input(capsys, ["init-cell", str(folder)], "mti_marker.yaml: already exists", "does not overwrite")
    assert (folder / "tools" / "mti_marker.yaml").read_text() == "mine\n"
    assert sorted(p.name for p in folder.rglob("*")) == ["mti_marker.yaml", "tools"]  # nothing else written
    afile = tmp_path / "f"
    afile.write_text("x")
    assert_bad_input(capsys, ["init-cell", str(afile)], "is a file")


def test_a_new_cell_from_init_to_an_evaluation_report(tmp_path, monkeypatch, capsys):
    """init-cell -> plan (the default optimal design, 49 poses) -> collect --sim -> export -> fit -> evaluate
    --report, every step on the new folder's cell."""
    pytest.importorskip("zenoh")
    monkeypatch.chdir(tmp_path)
    cell = ["--cell", "cell/cell.yaml"]
    assert main(["init-cell", "cell"]) == 0
    assert main([*cell, "plan", "--robot", "R1", "--out", "plan.json", "--budget", "49", "--validation", "6"]) == 0
    assert main([*cell, "collect", "--robot", "R1", "--plan", "plan.json", "--session", "s", "--sim",
                 "--time-scale", "200", "--no-progress"]) == 0
    assert main([*cell, "export", "--session", "s", "--out", "train.csv", "--kinds", "anchor,perturb"]) == 0
    assert main([*cell, "export", "--session", "s", "--out", "test.csv", "--kinds", "validation"]) == 0
    assert main([*cell, "fit", "--robot", "R1", "--train", "train.csv", "--method", "nls1", "--out", "m.yaml"]) == 0
    assert main([*cell, "evaluate", "--model", "m.yaml", "--test", "test.csv", "--report", "rep",
                 "--json", "e.json"]) == 0
    stats = json.loads((tmp_path / "e.json").read_text())
    assert (tmp_path / "rep" / "report.html").stat().st_size > 1000
    out = capsys.readouterr().out
    assert "49 samples of R1 -> train.csv" in out and "nls1 on 6 samples" in out, out
    assert json.dumps(stats)  # the evaluation's statistics were written


@pytest.mark.parametrize("rel", ["afile/sub", "afile/sub/deeper", "a" * 300, "x/" + "a" * 300])
def test_a_folder_that_cannot_be_made_is_one_line_and_nothing_is_left(tmp_path, monkeypatch, capsys, rel):
    """A folder under a file or with a name too long: one line naming it, exit 2, no folder left behind."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "afile").write_text("x")
    assert_bad_input(capsys, ["init-cell", rel], rel[:40])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


def test_a_folder_name_with_a_newline_gives_a_cell_that_loads(tmp_path):
    folder = tmp_path / "a\nb"
    assert main(["init-cell", str(folder)]) == 0
    assert load_cell(folder / "cell.yaml").robot("R1").name == "R1"
