"""Shared fixtures: a synthetic arm with planted errors and recordings generated from it."""

from __future__ import annotations

import os
from pathlib import Path

# One BLAS thread, as the CLI runs (app/cli/__init__.py), for these tests and the commands they start: the
# suite's products are small, and on a shared 2-core machine threaded BLAS calls stall and spin (measured on
# the Jacobian and round-trip tests: 33 s of CPU with two threads, 19 s with one).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402
import pytest

from calibration.data.recording import Recording
from calibration.kinematics import so3
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.methods.cdc import expand_anchors
from cell_config import load_cell

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "welding_motoman"
R1_TRAIN = SHARED_DATA / "PH_grad_data" / "test0801_R1"
R1_TEST = SHARED_DATA / "kinematic_raw_data" / "test0801_R1"


#: ``--time-scale`` of the tests that collect with ``--sim``: the simulated cell of every ``--sim`` command runs a
#: stepped clock (``SimCellOptions.deterministic``), so what it measures does not depend on the time scale, only
#: the real time its paced sleeps take (~3 s per recalibrate at the default 20, a tenth of that at 200).
SIM_FAST = ("--time-scale", "200")


def needs_shared_data() -> pytest.MarkDecorator:
    return pytest.mark.skipif(not (R1_TRAIN.exists() and R1_TEST.exists()),
                              reason=f"real recordings not found at {SHARED_DATA}")


def planted_parameters(par: MinimalParameterisation, seed: int = 1, offset_mm: float = 1.0,
                       tilt_rad: float = 1e-3) -> np.ndarray:
    """A random geometric error of realistic size."""
    rng = np.random.default_rng(seed)
    n = par.n_joints
    x = np.concatenate([rng.normal(0, offset_mm, 2 * n), rng.normal(0, tilt_rad, 2 * n)])
    if par.fit_tool:
        x = np.concatenate([x, rng.normal(0, offset_mm, 3)])
    return x


def cluster_design(step_deg: float = 15.0, spread_wrist: bool = True, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Anchors on a (q2, q3) grid, each with +1 deg on every joint: (q (N, 6), cluster (N,))."""
    rng = np.random.default_rng(seed)
    anchors = []
    for q2 in np.arange(-45.0, 46.0, step_deg):
        for q3 in np.arange(-40.0, 31.0, step_deg):
            other = rng.uniform(-40, 40, 4) if spread_wrist else np.ones(4)
            anchors.append([other[0], q2, q3, *other[1:]])
    return expand_anchors(np.radians(anchors))


def measure(truth_fk, q: np.ndarray, noise_mm: float, noise_deg: float, seed: int,
            cluster: np.ndarray | None = None) -> Recording:
    """A recording of ``truth_fk`` (q -> R, p) at q with Gaussian position and orientation noise."""
    rng = np.random.default_rng(seed)
    R, p = truth_fk(q)
    p = p + rng.normal(0, noise_mm, p.shape)
    R = so3.exp(rng.normal(0, np.radians(noise_deg), p.shape)) @ R
    extra = {} if cluster is None else {"cluster": cluster.astype(float)}
    return Recording(q, p, so3.R_to_quat(R), extra, "synthetic")


@pytest.fixture(scope="session", autouse=True)
def controller_claims(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The MotoROS links' controller claims (drivers.motoros.link.lock_dir) in a folder of this test session, for
    it and the commands it starts: the fake controllers' ports are new every test, and their claim files would
    pile up in the machine's /tmp/cellcal-locks."""
    folder = tmp_path_factory.mktemp("controller-claims")
    os.environ["CELLCAL_LOCK_DIR"] = str(folder)
    return folder


@pytest.fixture(scope="session")
def r1_nominal():
    return load_cell().robot("R1").model()


@pytest.fixture(scope="session")
def synthetic_arm(r1_nominal):
    """(parameterisation, planted x, truth model) for R1 with flange shift."""
    par = MinimalParameterisation(r1_nominal, fit_tool=True)
    x = planted_parameters(par)
    return par, x, par.model(x)


@pytest.fixture(scope="session")
def chromium(tmp_path_factory: pytest.TempPathFactory):
    """The headless browser of this test session (of this worker, under xdist), started at its first page; the
    tests that ask for it skip when no browser is installed. (Here, not in tests/app/conftest.py: a second module
    named ``conftest`` would shadow this one for the tests that import ``assert_bad_input`` from it.)"""
    from tests.app.browser import Chromium, browser_or_skip

    browser = Chromium(browser_or_skip(), tmp_path_factory.mktemp("chromium"))
    yield browser
    browser.close()


def gen_pages():
    """``docs/gen_pages.py`` (the docs site's generated pages: CLI reference, import graph), loaded as a module."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("gen_pages", Path(__file__).resolve().parents[1] / "docs" / "gen_pages.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def assert_bad_input(capsys: pytest.CaptureFixture, argv: list[str], *fragments: str) -> None:
    """The CLI exits 2 on ``argv`` with exactly one stderr line containing every fragment."""
    from app.cli.commands import main

    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    for f in fragments:
        assert f in err[0], err[0]


def backlash_case(n_q2: int = 5, n_q3: int = 4, n_heldout: int = 60):
    """A small diagnose case on R1 with planted backlash (seed 3): ``(nominal, gravity, fit, held-out)``."""
    from calibration.diagnosis.synthetic import Design, make_case
    from calibration.physics import GravityModel
    from cell_config import load_cell

    cr = load_cell().robot("R1")
    nominal = cr.model()
    gravity = GravityModel.from_spec(cr.robot, nominal)
    _, fit, ho = make_case(nominal, gravity, {"backlash": 0.3}, 3, Design(n_q2=n_q2, n_q3=n_q3), n_heldout=n_heldout)
    return nominal, gravity, fit, ho


def write_backlash_case(folder: Path, **sizes: int) -> tuple[Path, Path]:
    """:func:`backlash_case`'s fit and held-out recordings written as ``folder/fit.csv`` and ``folder/ho.csv``."""
    from calibration.data.recording import write_recording

    _, _, fit, ho = backlash_case(**sizes)
    write_recording(fit, folder / "fit.csv")
    write_recording(ho, folder / "ho.csv")
    return folder / "fit.csv", folder / "ho.csv"



# ---- running in parallel: `make test` runs `-n auto --dist loadscope --no-loadscope-reorder` (pytest-xdist) ----
# loadscope hands each worker whole modules, so a module's module-scoped fixtures (a demo run, a fit of the real
# recordings) are built once, and the rehearsal's real-time OS processes (tests/app/collection/test_rehearsal.py) run one
# test at a time, as in a serial run, while the other worker runs the CPU-bound modules beside them.
# (loadgroup cannot do the grouping: with pytest 9.2 it silently ignores xdist_group, pytest-xdist issue 1386.)

#: Modules that run first, longest first (summed test durations in a -n 2 run on the 2-core box), so the many short
#: modules fill in around them at the end instead of one long module running alone on one worker. Only the order
#: depends on this list: a module missing from it still runs, later. The rehearsal leads: it waits on real-time
#: OS processes, so the other worker's CPU-bound modules run beside it. test_preview is placed by its size with a
#: headless browser (without one its browser tests skip and it is short).
LONGEST_FIRST = ("tests/app/collection/test_rehearsal.py", "tests/test_readme.py", "tests/app/dual/test_preview.py",
                 "tests/drivers/test_motoros_driver.py", "tests/app/reports/test_report_signoff.py",
                 "tests/app/workflows/test_diagnose.py", "tests/app/workflows/test_demo_seed.py",
                 "tests/calibration/diagnosis/test_diagnosis.py", "tests/app/reports/test_report.py",
                 "tests/calibration/models/test_models.py", "tests/app/workflows/test_analysis_matrix.py",
                 "tests/calibration/methods/test_heldout.py", "tests/app/workflows/test_recalibrate.py",
                 "tests/drivers/test_natnet_client.py", "tests/app/collection/test_collect_verbose.py",
                 "tests/calibration/models/test_model_kinds.py", "tests/app/collection/test_collect_session.py",
                 "tests/app/cli/test_rebase_design_cli.py",
                 "tests/calibration/diagnosis/test_diagnosis_parsimony.py", "tests/app/cli/test_cli_frames.py",
                 "tests/app/collection/test_planning_safety.py", "tests/app/cli/test_cli_dual.py",
                 "tests/app/cli/test_cli.py", "tests/app/cli/test_staged_outputs.py",
                 "tests/app/dual/test_dual_plan.py", "tests/app/workflows/test_real_data.py",
                 "tests/calibration/frames/test_multiday.py", "tests/app/cli/test_cli_topup.py",
                 "tests/app/workflows/test_recalibrate_rebase.py", "tests/app/collection/test_collect_outcome.py")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """In an xdist worker, the modules of :data:`LONGEST_FIRST` move to the front (loadscope hands modules out in
    collection order). A serial run keeps pytest's order."""
    if not hasattr(config, "workerinput"):  # not an xdist worker
        return
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    order = {id(item): (rank.get(item.nodeid.split("::")[0], len(rank)), i) for i, item in enumerate(items)}
    items.sort(key=lambda item: order[id(item)])
