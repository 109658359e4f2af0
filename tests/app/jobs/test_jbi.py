"""Yaskawa INFORM jobs: byte-exact round trip, compensation under constant and CDC models, refusals, the CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("casadi")

from conftest import assert_bad_input, planted_parameters  # noqa: E402

from app.dual.export_targets import rpy_deg  # noqa: E402
from app.jobs import JobCompensator, JobError, parse_job, read_job, write_job  # noqa: E402
from calibration.kinematics import so3  # noqa: E402
from calibration.kinematics.parameterisation import MinimalParameterisation  # noqa: E402
from calibration.methods.cdc import geometric_cdc
from calibration.models import ConstantModel, save_model  # noqa: E402
from calibration.models.cdc import CdcModel  # noqa: E402
from cell_config.loader import load_cell  # noqa: E402
from tests.app.dual.test_dual_kinematics import FourierStub, OpaqueStub  # noqa: E402

Q_R1_DEG = [[0, 10, -10, 0, -30, 0], [20, 25, 5, 30, -45, 60], [-35, -20, 30, -60, -20, -120], [5, 40, -30, 10, -70, 200]]
Q_R2_DEG = [[0, 0, 0, 0, -40, 0], [-30, 20, -10, 45, -30, 90], [40, 35, 20, -20, -60, -150], [10, -30, 40, 0, -25, 15]]


@pytest.fixture(scope="module")
def cell():
    return load_cell()


def planted(cell, robot: str, seed: int = 1) -> ConstantModel:
    par = MinimalParameterisation(cell.robot(robot).model(), fit_tool=True)
    return ConstantModel(robot, "nls1", par.model(planted_parameters(par, seed=seed)))


def pulses(cell, robot: str, q_deg) -> list[str]:
    return [",".join(str(v) for v in cell.robot(robot).robot.to_pulses(np.radians(q))) for q in q_deg]


def crlf(lines: list[str]) -> bytes:
    return "".join(line + "\r\n" for line in lines).encode("ascii")


def single_job(cell, q_deg=Q_R1_DEG) -> bytes:
    p = pulses(cell, "R1", q_deg)
    moves = [f"MOVJ C{i:05d} VJ=10.00" if i % 2 == 0 else f"MOVL C{i:05d} V=50.0 PL=0" for i in range(len(p))]
    return crlf(["/JOB", "//NAME SPRAY1", "//POS", f"///NPOS {len(p)},0,0,0,0,0", "///TOOL 0", "///POSTYPE PULSE",
                 "///PULSE", *(f"C{i:05d}={v}" for i, v in enumerate(p)), "//INST", "///DATE 2026/12/01 12:00",
                 "///COMM calibrated spray", "///ATTR SC,RW", "///GROUP1 RB1", "NOP", "'spray pass", *moves,
                 "TIMER T=0.50", "END"])


def two_group_job(cell) -> bytes:
    lines, moves = [], []
    for i, (a, b) in enumerate(zip(pulses(cell, "R1", Q_R1_DEG), pulses(cell, "R2", Q_R2_DEG))):
        lines += ["///TOOL 0", f"C{2 * i:05d}={a}", "///TOOL 1", f"C{2 * i + 1:05d}={b}"]
        moves.append(f"MOVL C{2 * i:05d} V=11.0  +MOVL C{2 * i + 1:05d} V=11.0")
    moves.insert(2, "MOVC C00004 V=20.0  +MOVC C00005 V=20.0")  # a circle point shared with the MOVL below
    return crlf(["/JOB", "//NAME R1-R2", "//POS", "///NPOS 8,0,0,0,0,0", "///POSTYPE PULSE", "///PULSE", *lines,
                 "//INST", "///DATE 2026/12/01 12:00", "///ATTR SC,RW", "///GROUP1 RB1", "///GROUP2 RB2", "NOP",
                 *moves, "END"])


def cartesian_job(cell) -> bytes:
    """R1 with ROBOT and BASE positions (its nominal poses at Q_R1_DEG) and one PULSE position."""
    nominal = cell.robot("R1").model()
    R, p = nominal.fk(np.radians(Q_R1_DEG[:3]))
    rows = [",".join(f"{v:.3f}" for v in p[i]) + "," + ",".join(f"{v:.4f}" for v in rpy_deg(R[i])) for i in range(3)]
    return crlf(["/JOB", "//NAME CART", "//POS", "///NPOS 4,0,0,0,0,0", "///TOOL 0", "///POSTYPE ROBOT",
                 "///RECTAN", "///RCONF 0,0,0,0,0,0,0,0", f"C00000={rows[0]}", f"C00001={rows[1]}",
                 "///POSTYPE BASE", "///RECTAN", "///RCONF 0,0,0,0,0,0,0,0", f"C00002={rows[2]}",
                 "///POSTYPE PULSE", "///PULSE", f"C00003={pulses(cell, 'R1', Q_R1_DEG[3:])[0]}", "//INST",
                 "///DATE 2026/12/01 12:00", "///ATTR SC,RW", "///GROUP1 RB1", "NOP", "MOVJ C00000 VJ=5.00",
                 "MOVL C00001 V=20.0", "MOVL C00002 V=20.0", "MOVJ C00003 VJ=5.00", "END"])


# --- parse and write --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("make", [single_job, two_group_job, cartesian_job])
def test_job_round_trips_byte_for_byte(cell, make, tmp_path):
    data = make(cell)
    path = tmp_path / "IN.JBI"
    path.write_bytes(data)
    job = read_job(path)
    assert write_job(job) == data
    assert all(p.unit for p in job.positions) and len(job.positions) == sum(1 for r in job.raw_lines
                                                                             if r.startswith(b"C0"))


def test_round_trip_keeps_mixed_line_endings_and_foreign_bytes():
    data = single_job(load_cell()).replace(b"'spray pass\r\n", b"'\x83X\x83v\x83\x8c\x81[\n") + b"\r\n"
    assert write_job(parse_job(data)) == data


def test_parser_reads_groups_tools_and_postypes(cell):
    job = parse_job(two_group_job(cell))
    assert job.name == "R1-R2" and job.groups == (("RB1",), ("RB2",))
    units = {p.name: (p.unit, p.group, p.tool) for p in job.positions}
    assert units["C00000"] == ("RB1", 1, 0) and units["C00001"] == ("RB2", 2, 1)
    cart = parse_job(cartesian_job(cell))
    assert [p.postype for p in cart.positions] == ["ROBOT", "ROBOT", "BASE", "PULSE"]
    assert cart.positions[0].rconf == (0,) * 8 and cart.positions[3].rconf is None
    assert cart.positions[0].decimals == (3, 3, 3, 4, 4, 4)


def test_two_robots_in_one_group_take_the_cs_in_order(cell):
    data = two_group_job(cell).replace(b"///GROUP1 RB1\r\n///GROUP2 RB2\r\n", b"///GROUP1 RB1,RB2\r\n")
    data = data.replace(b"V=11.0  +MOVL C", b"C").replace(b"V=20.0  +MOVC C", b"C")
    job = parse_job(data)
    assert job.groups == (("RB1", "RB2"),)
    assert [p.unit for p in job.positions] == ["RB1", "RB2"] * 4


# --- compensation -----------------------------------------------------------------------------------------------

def _check_points(cell, comp, models, job):
    for pt in comp.points:
        assert pt.residual_mm <= 1e-6 and pt.residual_deg <= 1e-6, pt
        spec = cell.robot(pt.robot).robot
        if pt.postype == "PULSE":  # the solved q reaches the nominal pose under the model, to 1e-6 mm
            nominal = cell.robot(pt.robot).model()
            q = np.radians(pt.q_after_deg)
            R_n, p_n = nominal.fk(spec.from_pulses(np.array(pt.before))[None])
            R_c, p_c = models[pt.robot].fk(q[None])
            assert np.linalg.norm(p_c - p_n) <= 1e-6
            assert np.all(q >= spec.lower_rad) and np.all(q <= spec.upper_rad)
            # one pulse of the finest joint moves the tool by < 0.05 mm on these arms
            assert pt.written_residual_mm < 0.05 and pt.after == spec.to_pulses(q).tolist()
        assert 0 < np.abs(pt.joint_change_deg).max() < 3.0  # the planted error is ~1 mm, 1 mrad per joint


def test_pulse_job_is_compensated_to_the_nominal_poses(cell):
    models = {"R1": planted(cell, "R1")}
    job = parse_job(single_job(cell))
    comp = JobCompensator(cell, models).compensate(job)
    assert len(comp.points) == 4 and sorted(comp.replacements) == [p.line for p in job.positions]
    _check_points(cell, comp, models, job)
    out = parse_job(write_job(job, comp.replacements))
    assert [list(p.values) for p in out.positions] == [p.after for p in comp.points]
    changed = [i for i, (a, b) in enumerate(zip(job.raw_lines, out.raw_lines), 1) if a != b]
    assert changed == sorted(comp.replacements) and all(r.endswith(b"\r\n") for r in out.raw_lines)


def test_two_group_job_is_compensated_for_both_robots(cell):
    models = {"R1": planted(cell, "R1", 1), "R2": planted(cell, "R2", 2)}
    job = parse_job(two_group_job(cell))
    comp = JobCompensator(cell, models).compensate(job)
    assert [p.robot for p in comp.points] == ["R1", "R2"] * 4
    _check_points(cell, comp, models, job)
    with pytest.raises(JobError, match=r"line 10: C00001 is R2's \(RB2\) and no model was given for R2"):
        JobCompensator(cell, {"R1": models["R1"]}).compensate(job)


@pytest.mark.parametrize("stub", [FourierStub, OpaqueStub], ids=["cdc", "cdc-frozen"])
def test_cdc_model_is_solved_with_its_configuration_dependent_parameters(cell, stub):
    par = MinimalParameterisation(cell.robot("R1").model())
    model = CdcModel("R1", "fbf13", *geometric_cdc(par), stub(par.size, scale=2e-3))
    job = parse_job(single_job(cell))
    comp = JobCompensator(cell, {"R1": model}).compensate(job)
    _check_points(cell, comp, {"R1": model}, job)


def test_cartesian_positions_become_the_nominal_pose_of_the_calibrated_solution(cell):
    model = planted(cell, "R1")
    job = parse_job(cartesian_job(cell))
    comp = JobCompensator(cell, {"R1": model}).compensate(job)
    nominal = cell.robot("R1").model()
    for pt, pos in zip(comp.points[:3], job.positions):
        p_t = np.array(pos.values[:3])
        R_c, p_c = model.fk(np.radians(pt.q_after_deg)[None])
        assert np.linalg.norm(p_c[0] - p_t) <= 1e-6 and pt.residual_deg <= 1e-6
        R_w, p_w = nominal.fk(np.radians(pt.q_after_deg)[None])  # what is written: nominal pose at q_cal
        np.testing.assert_allclose(pt.after[:3], p_w[0], atol=5e-4)
        assert pt.written_residual_mm < 5e-3  # 0.001 mm and 0.0001 deg of the file's decimals
        np.testing.assert_allclose(pt.q_before_deg, Q_R1_DEG[job.positions.index(pos)], atol=1e-3)
    _check_points(cell, comp, {"R1": model}, job)


def test_out_of_limit_point_is_refused_naming_the_line(cell):
    q = [list(r) for r in Q_R1_DEG]
    q[2][4] = 95.0  # joint 5 beyond +90
    with pytest.raises(JobError, match=r"line 10: C00002: programmed R1 joint 5 at 95\.\d+ deg is outside the "
                                       r"limit 90 deg"):
        JobCompensator(cell, {"R1": planted(cell, "R1")}).compensate(parse_job(single_job(cell, q)))


def test_point_only_the_nominal_arm_reaches_within_limits_is_refused(cell):
    q = [list(r) for r in Q_R1_DEG]
    q[1][4] = 89.999  # on joint 5's limit (+90): the calibrated arm may need to go beyond it
    model = planted(cell, "R1")
    job = parse_job(single_job(cell, q))
    try:
        comp = JobCompensator(cell, {"R1": model}).compensate(job)
    except JobError as e:
        assert e.line == 9 and "cannot reach this pose within its joint limits" in e.reason
    else:
        assert comp.points[1].q_after_deg[4] <= 90.0 and comp.points[1].residual_mm <= 1e-6


def test_cartesian_branch_follows_rconf_flip(cell):
    data = cartesian_job(cell)
    model = planted(cell, "R1")

    def rconf(name: bytes, flags: bytes) -> bytes:
        return data.replace(b"///RCONF 0,0,0,0,0,0,0,0\r\n" + name, b"///RCONF " + flags + b"\r\n" + name)

    no_flip = rconf(b"C00002", b"1,0,0,0,0,0,0,0")  # R outside (-90, 90]: the wrist-flipped solution, R = 120
    comp = JobCompensator(cell, {"R1": model}).compensate(parse_job(no_flip))
    assert abs(comp.points[2].q_after_deg[3]) > 90 and comp.points[2].residual_mm <= 1e-6
    assert abs(comp.points[3].q_after_deg[3]) <= 90
    for flags, line in ((b"1,0,0,0,0,0,0,0", 9), (b"0,0,0,0,1,0,0,0", 9)):  # no-flip needs R = 180; T >= 180
        with pytest.raises(JobError, match=rf"line {line}: C00000: the nominal R1 reaches this pose nowhere within "
                                           r"its joint limits and ///RCONF"):
            JobCompensator(cell, {"R1": model}).compensate(parse_job(rconf(b"C00000", flags)))
    user = data.replace(b"///POSTYPE BASE", b"///POSTYPE USER")
    with pytest.raises(JobError, match=r"line 14: C00002: ///POSTYPE USER positions are not compensated"):
        JobCompensator(cell, {"R1": model}).compensate(parse_job(user))


def test_two_robots_in_one_group_are_compensated(cell):
    data = two_group_job(cell).replace(b"///GROUP1 RB1\r\n///GROUP2 RB2\r\n", b"///GROUP1 RB1,RB2\r\n")
    data = data.replace(b"V=11.0  +MOVL C", b"C").replace(b"V=20.0  +MOVC C", b"C")
    models = {"R1": planted(cell, "R1", 1), "R2": planted(cell, "R2", 2)}
    comp = JobCompensator(cell, models).compensate(parse_job(data))
    assert [(p.robot, p.group) for p in comp.points] == [("R1", 1), ("R2", 1)] * 4
    _check_points(cell, comp, models, parse_job(data))


def test_big_joint_change_near_the_wrist_singularity_is_refused_when_the_nearest_solution_leaves_too_much(
        cell, tmp_path, capsys):
    from app.cli.commands import main

    q = [list(r) for r in Q_R1_DEG]
    q[0][4] = -0.5  # q5 ~ 0: the exact orientation fix swings joints 4 and 6 (about 10 deg here)
    data = single_job(cell, q)
    model = planted(cell, "R1")
    comp = JobCompensator(cell, {"R1": model}).compensate(parse_job(data))  # the nearest solution: under a degree
    assert comp.points[0].near_singularity and np.abs(comp.points[0].joint_change_deg).max() < 1.0
    with pytest.raises(JobError, match=r"line 8: C00000: compensation moves R1 joint \d by [\d.]+ deg, more than "
                                       r"the 5 deg allowed \(joint 5 at -0\.50 deg; near q5 = 0 the wrist is singular; "
                                       r"the solution nearest the programmed joints leaves the orientation [\d.]+ deg "
                                       r"off, more than the 0\.001 deg allowed\)"):
        JobCompensator(cell, {"R1": model}, near_orientation_deg=1e-3).compensate(parse_job(data))
    job, out, m = tmp_path / "IN.JBI", tmp_path / "OUT.JBI", tmp_path / "r1.yaml"
    job.write_bytes(data)
    save_model(model, m)
    assert main(["compensate-job", "--model", str(m), "--job", str(job), "--out", str(out),
                 "--near-orientation-deg", "0.001", "--max-joint-change-deg", "180"]) == 0
    assert out.exists() and "4 positions" in capsys.readouterr().out


def _wrist_singular_job(cell, rng) -> list[list[float]]:
    """Home (every joint 0), q5 = 0 exactly with the other joints anywhere, and |q5| < 1 deg."""
    q = [[0.0] * 6]
    for q5 in (0.0, 0.0, 0.2, -0.5, 0.9, -0.99):
        q.append([*rng.uniform(-40, 40, 4), q5, rng.uniform(-150, 150)])
    return q


@pytest.mark.parametrize("seed", [1, 2])
def test_points_at_the_wrist_singularity_take_the_solution_nearest_the_taught_joints(cell, seed):
    """At q5 ~ 0 only q4 + q6 is determined: the exact orientation fix swings joints 4 and 6 by up to 75 deg
    against each other (issue 31: 74.27 deg at a job's home under fbf13 of 0801). The compensation reaches the
    position and leaves the orientation within NEAR_ORIENTATION_DEG, every joint moved by under a degree."""
    from app.jobs.compensate import NEAR_ORIENTATION_DEG

    par = MinimalParameterisation(cell.robot("R1").model(), fit_tool=True)
    model = ConstantModel("R1", "nls1", par.model(planted_parameters(par, seed=seed, offset_mm=0.5, tilt_rad=5e-4)))
    q_deg = _wrist_singular_job(cell, np.random.default_rng(seed))
    comp = JobCompensator(cell, {"R1": model}).compensate(parse_job(single_job(cell, q_deg)))
    spec, nominal = cell.robot("R1").robot, cell.robot("R1").model()
    for pt in comp.points:
        q = np.radians(pt.q_after_deg)
        R_n, p_n = nominal.fk(spec.from_pulses(np.array(pt.before))[None])
        R_c, p_c = model.fk(q[None])
        assert np.linalg.norm(p_c - p_n) <= 1e-6  # the position reached
        angle = np.degrees(np.linalg.norm(so3.log(R_n[0].T @ R_c[0])))
        assert angle <= NEAR_ORIENTATION_DEG and abs(angle - pt.residual_deg) < 1e-6
        assert np.abs(pt.joint_change_deg).max() < 1.0, pt
        assert pt.written_residual_mm < 0.05
    assert sum(pt.near_singularity for pt in comp.points) >= 3  # the exact solution would have swung the wrist


def test_pulse_conversion_round_trips_through_the_job(cell):
    spec = cell.robot("R2").robot
    q = np.radians(Q_R2_DEG)
    job = parse_job(two_group_job(cell))
    got = np.array([p.values for p in job.positions if p.unit == "RB2"])
    np.testing.assert_array_equal(got, spec.to_pulses(q))
    np.testing.assert_allclose(spec.from_pulses(got), q, atol=0.5 / spec.pulses_per_rad.min())


# --- bad input --------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("edit, line, reason", [
    (lambda d: d.replace(b"C00001=", b"C00001=1,2,"), 9, "malformed position C00001: expected 6 integer pulses"),
    (lambda d: d.replace(b"C00002=", b"C00002=x"), 10, "malformed position C00002"),
    (lambda d: d.replace(b"///GROUP1 RB1", b"///GROUP1 RB7"), 8, "unknown group unit 'RB7'; valid: RB1 (R1), RB2"),
    (lambda d: d.replace(b"MOVL C00003", b"MOVL C00002"), 11, "C00003 is not used by any move instruction"),
    (lambda d: d.replace(b"///POSTYPE PULSE", b"///POSTYPE ANGLE"), 6, "unknown ///POSTYPE 'ANGLE'"),
    (lambda d: d.replace(b"/JOB", b"JOB"), 1, "expected '/JOB'"),
    (lambda d: d.replace(b"//INST", b"P00100=0,0,0,0,0,0\r\n//INST").replace(b"NPOS 4,0,0,0", b"NPOS 4,0,0,1"), 12,
     "P00100 is a robot position variable"),
    (lambda d: d.replace(b"NPOS 4,", b"NPOS 5,"), 4, "///NPOS 5,0,0,0,0,0 disagrees with the //POS section, which "
                                                    "holds 4 C, 0 BC, 0 EC, 0 P, 0 BP, 0 EX"),
    (lambda d: d.replace(b"//INST", b"P00100=0,0,0,0,0,0\r\n//INST"), 4, "which holds 4 C, 0 BC, 0 EC, 1 P"),
])
def test_bad_job_exits_2_naming_file_and_line(cell, tmp_path, capsys, edit, line, reason):
    model = tmp_path / "r1.yaml"
    save_model(planted(cell, "R1"), model)
    job, out = tmp_path / "IN.JBI", tmp_path / "OUT.JBI"
    job.write_bytes(edit(single_job(cell)))
    assert_bad_input(capsys, ["compensate-job", "--model", str(model), "--job", str(job), "--out", str(out)],
                     f"{job}, line {line}: ", reason)
    assert not out.exists()


@pytest.mark.parametrize("kind, reason", [("missing", "job file not found"), ("dir", "found a directory"),
                                          ("binary", "binary data"), ("empty", "expected '/JOB'")])
def test_unreadable_job_exits_2(cell, tmp_path, capsys, kind, reason):
    model = tmp_path / "r1.yaml"
    save_model(planted(cell, "R1"), model)
    job, out = tmp_path / "IN.JBI", tmp_path / "OUT.JBI"
    if kind == "dir":
        job.mkdir()
    elif kind == "binary":
        job.write_bytes(b"/JOB\r\n\x00\x01\x02")
    elif kind == "empty":
        job.write_bytes(b"")
    assert_bad_input(capsys, ["compensate-job", "--model", str(model), "--job", str(job), "--out", str(out)],
                     str(job), reason)
    assert not out.exists()


def test_bad_model_arguments_exit_2(cell, tmp_path, capsys):
    job, out = tmp_path / "IN.JBI", tmp_path / "OUT.JBI"
    job.write_bytes(single_job(cell))
    r2 = tmp_path / "r2.yaml"
    save_model(planted(cell, "R2"), r2)
    binary = tmp_path / "bin.yaml"
    binary.write_bytes(b"\xff\xfe\x00\x01")
    base = ["compensate-job", "--job", str(job), "--out", str(out)]
    assert_bad_input(capsys, base + ["--model", f"R1={r2}"], "fitted for R2", "R1")
    assert_bad_input(capsys, base + ["--model", str(binary)], str(binary))
    assert_bad_input(capsys, base + ["--model", f"R3={r2}"], "R3", "valid: R1, R2")
    assert_bad_input(capsys, base + ["--model", str(r2), "--out", str(job)],
                     "--out is also the --job input; refusing to overwrite it")
    assert_bad_input(capsys, base + ["--model", str(r2), "--out", str(job / "OUT.JBI")], "lies under a file")
    assert_bad_input(capsys, base + ["--model", str(r2), "--json", str(tmp_path)], str(tmp_path), "folder")
    assert_bad_input(capsys, base + ["--model", str(r2), "--out", ""], "empty")
    assert not out.exists()


def test_a_model_with_another_robot_types_geometry_is_refused_naming_the_file(cell, tmp_path, capsys):
    """A file recording R1 but holding the MA1440's geometry was taken: the job's first point was then refused as
    'cannot reach this pose within its joint limits', and a closer wrong geometry would have been written."""
    job, out = tmp_path / "IN.JBI", tmp_path / "OUT.JBI"
    job.write_bytes(single_job(cell))
    wrong = tmp_path / "r1_of_an_ma1440.yaml"
    save_model(ConstantModel("R1", "nls1", cell.robot("R2").model()), wrong)
    assert_bad_input(capsys, ["compensate-job", "--model", str(wrong), "--job", str(job), "--out", str(out)],
                     str(wrong), "geometry: not R1's geometry")
    assert not out.exists()


# --- the command ------------------------------------------------------------------------------------------------

def test_cli_writes_the_compensated_job_and_its_json(cell, tmp_path, capsys):
    from app.cli.commands import main

    m1, m2 = tmp_path / "r1.yaml", tmp_path / "r2.json"
    save_model(planted(cell, "R1", 1), m1)
    save_model(planted(cell, "R2", 2), m2)
    job, out, report = tmp_path / "IN.JBI", tmp_path / "out" / "OUT.JBI", tmp_path / "comp.json"
    job.write_bytes(two_group_job(cell))
    assert main(["compensate-job", "--model", str(m1), "--model", f"R2={m2}", "--job", str(job), "--out", str(out),
                 "--json", str(report)]) == 0
    assert "8 positions" in capsys.readouterr().out
    data = json.loads(report.read_text())
    assert data["schema"] == "cellcal.compensated_job/1" and len(data["points"]) == 8
    first = data["points"][0]
    assert {"line", "group", "before", "after", "joint_change_deg", "residual_mm"} <= set(first)
    assert first["line"] == 8 and first["group"] == 1 and data["points"][1]["group"] == 2
    assert max(p["residual_mm"] for p in data["points"]) <= 1e-6
    written = read_job(out)
    assert [list(map(int, p.values)) for p in written.positions] == [p["after"] for p in data["points"]]
    original = job.read_bytes().splitlines(keepends=True)
    kept = [a == b for a, b in zip(original, out.read_bytes().splitlines(keepends=True))]
    assert sum(not k for k in kept) == 8 and len(original) == len(written.raw_lines)
