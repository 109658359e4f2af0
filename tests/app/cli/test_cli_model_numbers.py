"""Every model-reading command refuses a model file holding a bad number, naming the key (issue 30, safety).

The reliability pass typed ``nan``, ``inf`` and ``1e308`` into model files by hand (YAML reads them as text):
predict wrote nan poses and export-urdf xyz="nan ..." with exit 0, compensate-job and plan-dual ended in a
LinAlgError traceback. Here each command gets such a file in the base link, the tool and a rotation.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from app.cli.commands import main
from calibration.models import ConstantModel, save_model
from cell_config.loader import load_cell
from tests.conftest import cluster_design, measure

#: (file edit, key the message must name): base link and tool typed by hand, a NaN in a rotation (JSON NaN).
EDITS = {"base nan": (r"(  P:\n  - \[)[^,]*", r"\g<1>nan", "geometry.P[0][0]"),
         "tool 1e308": (r"(  p_flange_tool: \[)[^,]*", r"\g<1>1e308", "geometry.p_flange_tool[0]"),
         "rotation inf": (r"(  R_flange:\n  - \[)[^,]*", r"\g<1>inf", "geometry.R_flange[0][0]")}


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    from calibration.data.recording import write_recording

    root = tmp_path_factory.mktemp("model_numbers")
    cell = load_cell()
    nominal = cell.robot("R1").model()
    q, cluster = cluster_design(step_deg=30.0)
    write_recording(measure(nominal.fk, q, 0.02, 0.01, 1, cluster), root / "train.csv")
    q_test = np.random.default_rng(3).uniform(-0.8, 0.8, (40, 6))
    write_recording(measure(nominal.fk, q_test, 0.02, 0.01, 2), root / "test.csv")
    np.savetxt(root / "q.csv", q_test[:5], delimiter=",")
    save_model(ConstantModel("R1", "nls1", nominal, 27, {}), root / "r1.yaml")
    text = (root / "r1.yaml").read_text()
    for name, (pattern, repl, _) in EDITS.items():
        edited, n = re.subn(pattern, repl, text, count=1)
        assert n == 1, name
        (root / f"{name.replace(' ', '_')}.yaml").write_text(edited)
    from tests.app.jobs.test_jbi import single_job

    (root / "IN.JBI").write_bytes(single_job(cell))
    return root


def _commands(root, model, out):
    return {"predict": ["predict", "--model", model, "--joints", str(root / "q.csv"), "--out", out],
            "evaluate": ["evaluate", "--model", model, "--test", str(root / "test.csv"), "--json", out],
            "rebase": ["rebase", "--model", model, "--data", str(root / "train.csv"), "--out", out],
            "export-urdf": ["export-urdf", "--model", model, "--out", out],
            "compare": ["compare", "--robot", "R1", "--train", str(root / "train.csv"), "--test",
                        str(root / "test.csv"), "--methods", "nominal", "--model", model, "--json", out],
            "diagnose": ["diagnose", "--robot", "R1", "--train", str(root / "train.csv"), "--model", model,
                         "--json", out],
            "compensate-job": ["compensate-job", "--model", model, "--job", str(root / "IN.JBI"), "--out", out],
            "plan-dual": ["plan-dual", "--models", f"R1={model}", "--path", "sweep:3", "--out", out],
            "export-targets": ["export-targets", "--plan", str(root / "missing-plan.json"), "--models",
                               f"R1={model}", "--out", out],
            "validate-dual": ["validate-dual", "--sim", "--models", f"R1={model}", "--json", out]}


@pytest.mark.parametrize("edit", sorted(EDITS))
@pytest.mark.parametrize("command", sorted(_commands(Path("."), "", "")))
def test_every_model_reading_command_refuses_a_bad_number_naming_the_key(files, tmp_path, capsys, command, edit):
    if command in ("plan-dual", "export-targets", "validate-dual"):
        pytest.importorskip("casadi")
    model = str(files / f"{edit.replace(' ', '_')}.yaml")
    out = tmp_path / ("out.JBI" if command == "compensate-job" else "out.json" if command in
                      ("evaluate", "compare", "diagnose", "plan-dual", "validate-dual", "export-targets")
                      else "out.csv" if command == "predict" else "out.yaml" if command == "rebase" else "out.urdf")
    assert main(_commands(files, model, str(out))[command]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{EDITS[edit][2]}: expected a" in err[0], err
    assert not out.exists()
