"""The diagnosis verdict names every candidate the data could not show, whatever it acts on."""

from __future__ import annotations

import pytest

from calibration.diagnosis.candidates import KINDS, Untested
from calibration.diagnosis.explain import PHYSICS, verdict
from calibration.diagnosis.report import Accuracy

ACC = Accuracy("geometric", 0.35, 0.43, 0.04, 0.05)


def _hidden(kind: str, joints: tuple[int, ...]) -> list[Untested]:
    if not joints:  # what the candidate acts on has no joint: links, the tool marker, the whole arm
        return [Untested(kind, "link p12", (), "not identifiable"), Untested(kind, "link p23", (), "not identifiable")]
    return [Untested(kind, f"joint {j}", (j,), "not identifiable") for j in joints]


@pytest.mark.parametrize("kind", [k for k in KINDS if k != "joint_offset"])
@pytest.mark.parametrize("joints", [(), (2,), (2, 3)])
def test_every_hidden_candidate_is_named(kind, joints):
    """A hidden candidate acting on no joint (thermal drift of links p12 ... p6T on a short simulated recording) made
    the verdict raise IndexError, ending ``cellcal diagnose`` in a traceback; it is named by its label."""
    hidden = _hidden(kind, joints)
    text = verdict([], ACC, ACC, 0.013, hidden, [])
    assert "Not identifiable from this data" in text and PHYSICS[kind] in text
    for u in hidden:
        assert (u.label if not u.joints else str(u.joints[0])) in text


def test_joints_and_labels_of_one_kind_are_both_named():
    hidden = [Untested("thermal_drift", "link p12", (), "r"), Untested("thermal_drift", "link p23", (), "r"),
              Untested("joint_compliance", "joint 2", (2,), "r"), Untested("joint_compliance", "joint 3", (3,), "r")]
    text = verdict([], ACC, ACC, 0.013, hidden, [])
    assert "joint compliance under gravity on joints 2 and 3" in text
    assert "thermal drift on link p12 and link p23" in text
