"""The bad-input replay (scripts/studies/replay_bad_inputs.py) on a handful of its cases that need none of its good inputs
(so no fit or plan is made first): each must end clean (one line, exit 2, nothing written) within its timeout, as
the replayed subprocess the script runs."""

from scripts.studies.replay_bad_inputs import FAMILIES, cases, replay, table

SUBSET = ("recordings: a FIFO", "plans: export-targets: nested 200,000 deep", "models: /dev/zero", "cells: a FIFO")


def test_every_family_has_cases_and_the_subset_exists():
    by_name = {f"{c.family}: {c.name}": c for c in cases()}
    assert set(SUBSET) <= set(by_name)
    assert {c.family for c in cases()} == set(FAMILIES)


def test_a_handful_of_bad_inputs_end_clean(tmp_path):
    by_name = {f"{c.family}: {c.name}": c for c in cases()}
    (tmp_path / "cell").mkdir()
    outcomes = [replay(by_name[name], tmp_path, 20.0) for name in SUBSET]
    assert [(o.name, o.verdict, o.stderr) for o in outcomes if o.verdict != "clean"] == []
    assert table(outcomes).splitlines()[-1].split()[:3] == ["total", str(len(SUBSET)), str(len(SUBSET))]
