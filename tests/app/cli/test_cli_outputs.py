"""Every output path of the CLI: atomic, the user's umask, never over a symlink, a device, a FIFO or a folder."""

import json
import os
import stat

from app.cli.commands import main
from tests.conftest import assert_bad_input

PLAN = ["plan", "--design", "grid", "--robot", "R1", "--q2-step", "30", "--q3-step", "30", "--out"]


def _mode(path):
    return stat.S_IMODE(os.stat(path).st_mode)


def test_plan_out_follows_the_umask_and_keeps_an_existing_mode(tmp_path):
    old = os.umask(0o027)
    try:
        assert main(PLAN + [str(tmp_path / "new.json")]) == 0
    finally:
        os.umask(old)
    assert _mode(tmp_path / "new.json") == 0o640
    existing = tmp_path / "existing.json"
    existing.write_text("{}")
    os.chmod(existing, 0o644)
    old = os.umask(0o077)
    try:
        assert main(PLAN + [str(existing)]) == 0
    finally:
        os.umask(old)
    assert _mode(existing) == 0o644 and json.loads(existing.read_text())["targets"]


def test_plan_out_over_a_symlink_fifo_or_folder_is_refused_and_nothing_changes(tmp_path, capsys):
    real = tmp_path / "real.json"
    real.write_text("keep")
    link = tmp_path / "link.json"
    link.symlink_to(real)
    assert_bad_input(capsys, PLAN + [str(link)], "link.json", "is a symbolic link; refusing to replace it")
    assert link.is_symlink() and real.read_text() == "keep"
    fifo = tmp_path / "plan.fifo"
    os.mkfifo(fifo)
    assert_bad_input(capsys, PLAN + [str(fifo)], "plan.fifo", "is a FIFO; refusing to replace it")
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert_bad_input(capsys, PLAN + [str(tmp_path)], "is a folder")
    assert_bad_input(capsys, PLAN + [str(real / "under.json")], "not a folder")
    assert_bad_input(capsys, PLAN + [""], "empty output path")
    assert sorted(os.listdir(tmp_path)) == ["link.json", "plan.fifo", "real.json"]


def test_json_to_a_device_is_refused_before_any_work(tmp_path, capsys):
    # --json /dev/full used to replace the device node with a regular file when run as root
    assert_bad_input(capsys, ["evaluate", "--model", str(tmp_path / "missing.yaml"), "--test",
                              str(tmp_path / "missing.csv"), "--json", "/dev/null"],
                     "/dev/null: is a character device; refusing to replace it")
    assert stat.S_ISCHR(os.lstat("/dev/null").st_mode)


def test_a_failed_plan_write_leaves_the_old_plan_whole_and_no_temporary(tmp_path, capsys, monkeypatch):
    path = tmp_path / "plan.json"
    assert main(PLAN + [str(path)]) == 0
    before = path.read_bytes()

    def full(*args, **kwargs):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(os, "fsync", full)
    assert_bad_input(capsys, PLAN[:6] + ["15", "--q3-step", "15", "--out", str(path)],
                     "plan.json: cannot write (No space left on device)")
    monkeypatch.undo()
    assert path.read_bytes() == before and os.listdir(tmp_path) == ["plan.json"]


def test_an_output_that_is_an_input_or_another_output_is_refused_and_nothing_changes(tmp_path, capsys):
    # fit --out equal to --train replaced the recording with the model, --json equal to --out the model with its
    # summary, plan --out the packaged cell.yaml (read when --cell is left out)
    from cell_config import DEFAULT_CELL

    plan = tmp_path / "plan.json"
    assert main(PLAN + [str(plan)]) == 0
    joints = tmp_path / "q.csv"
    joints.write_text("q1,q2,q3,q4,q5,q6\n0,0,0,0,0,0\n")
    cell_before = DEFAULT_CELL.read_bytes()
    try:
        assert_bad_input(capsys, PLAN + [str(DEFAULT_CELL)], "cell.yaml: --out is also the --cell input",
                         "refusing to overwrite it")
    finally:
        written = DEFAULT_CELL.read_bytes()
        DEFAULT_CELL.write_bytes(cell_before)  # never leave the packaged cell replaced, even when the test fails
    assert written == cell_before
    before = {p: p.read_bytes() for p in (plan, joints)}
    assert_bad_input(capsys, PLAN + [str(plan), "--json", str(tmp_path / "." / "plan.json")],
                     "--json is also the --out output")
    assert_bad_input(capsys, PLAN + [str(tmp_path / "new.json"), "--json", str(tmp_path / "new.json")],
                     "new.json: --json is also the --out output")
    assert_bad_input(capsys, ["predict", "--model", str(plan), "--joints", str(joints), "--out", str(joints)],
                     "q.csv: --out is also the --joints input")
    assert_bad_input(capsys, ["plan-dual", "--models", f"R1={plan}", "--out", str(plan)],
                     "--out is also the --models input")
    assert {p: p.read_bytes() for p in (plan, joints)} == before
    assert sorted(os.listdir(tmp_path)) == ["plan.json", "q.csv"]


def test_an_output_onto_a_file_a_given_folder_holds_is_refused_and_nothing_changes(tmp_path, capsys):
    # export --out S/session.sqlite replaced the session it read with the CSV; recalibrate --json M/current.yaml
    # would replace the model it installs (there is none yet in a new model folder: compared by path)
    session, models = tmp_path / "s", tmp_path / "models"
    session.mkdir()
    models.mkdir()
    (session / "session.sqlite").write_bytes(b"the session")
    assert_bad_input(capsys, ["export", "--session", str(session), "--out", str(session / "." / "session.sqlite")],
                     "session.sqlite: --out is also the --session folder's session.sqlite", "refusing to overwrite")
    for present in (False, True):
        if present:
            (models / "current.yaml").write_text("the model in service")
        assert_bad_input(capsys, ["recalibrate", "--robot", "R1", "--plan", str(tmp_path / "plan.json"),
                                  "--model-dir", str(models), "--sim", "--json", str(models / "current.yaml")],
                         "current.yaml: --json is also the --model-dir folder's current.yaml")
    assert (session / "session.sqlite").read_bytes() == b"the session"
    assert (models / "current.yaml").read_text() == "the model in service"
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["current.yaml", "models", "s", "session.sqlite"]


def test_export_writes_a_csv_and_an_empty_kinds_list_is_refused(tmp_path, capsys):
    """export --out x.json wrote CSV into a .json file, and --kinds "" exported every kind (new-user run); both are
    refused before the session is read."""
    session = tmp_path / "s"
    for argv, message in ((["--out", str(tmp_path / "x.json")], "a recording is a CSV file (.csv); got .json suffix"),
                          (["--out", str(tmp_path / "x.csv"), "--kinds", ""], "unknown target kind ''")):
        assert_bad_input(capsys, ["export", "--session", str(session), *argv], message)
    assert sorted(p.name for p in tmp_path.iterdir()) == []
