"""The sign-off verdict of a report: the model one section puts into service, accepted, accepted with conditions or
not accepted against the tolerance, its conditions being every warning the run gave (:mod:`app.reports.page`
renders it at the top of the page)."""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

from app.reports.acceptance import Acceptance, Tolerance


class Judged(Protocol):
    """What a verdict reads of a report section (:class:`app.reports.page.Section`, which renders the verdict)."""

    @property
    def title(self) -> str: ...
    @property
    def acceptance(self) -> Sequence[Acceptance]: ...
    @property
    def acceptance_data(self) -> str: ...
    @property
    def conditions(self) -> Sequence[str]: ...
    @property
    def in_service(self) -> str | None: ...

ACCEPTED, CONDITIONAL, NOT_ACCEPTED = "accepted", "accepted with conditions", "not accepted"


@dataclass(frozen=True)
class Verdict:
    """The sign-off verdict on the model one section puts into service.

    Attributes:
        subject: what is judged (the section's title: a robot, a question).
        model: the model put into service, or None when the section names none.
        status: :data:`ACCEPTED`, :data:`CONDITIONAL` (within the tolerance, with warnings) or :data:`NOT_ACCEPTED`
            (outside the tolerance, or no model to judge).
        reason: the figures behind it, in one sentence.
        conditions: every warning the run gave (the command's and this section's), each once.
    """

    subject: str
    model: str | None
    status: str
    reason: str
    conditions: tuple[str, ...]

    @property
    def css(self) -> str:
        return {ACCEPTED: "accepted", CONDITIONAL: "conditional"}.get(self.status, "rejected")


def verdict(section: Judged, tol: Tolerance, command_warnings: list[str]) -> Verdict:
    """The verdict on ``section``'s model for service against ``tol``, its conditions the warnings given."""
    conditions = tuple(dict.fromkeys([*command_warnings, *section.conditions]))
    model = section.in_service
    acc = next((a for a in section.acceptance if a.model == model), None)
    if acc is None:
        return Verdict(section.title, model, NOT_ACCEPTED, "no model was chosen to put into service", conditions)
    figures = (f"{acc.model}: largest errors {acc.max_position_mm:.3f} mm and {acc.max_orientation_deg:.3f} deg on "
               f"{section.acceptance_data}, against {tol.position_mm:g} mm and {tol.orientation_deg:g} deg")
    if not acc.passed:
        return Verdict(section.title, model, NOT_ACCEPTED, figures + ": outside the tolerance", conditions)
    return Verdict(section.title, model, CONDITIONAL if conditions else ACCEPTED, figures + ": within the tolerance",
                   conditions)


def page_verdict(verdicts: list[Verdict]) -> str:
    """One status for the page: the worst of its sections'."""
    order = [ACCEPTED, CONDITIONAL, NOT_ACCEPTED]
    return max((v.status for v in verdicts), key=order.index, default=NOT_ACCEPTED)


def default_next_steps(v: Verdict) -> list[str]:
    """What to do after a verdict when the command gave no more specific step."""
    if v.status == NOT_ACCEPTED:
        return [f"Do not put {v.model or 'a model'} into service. Find what the model misses where it fails "
                "(cellcal diagnose --robot ROBOT --train TRAIN --test TEST) and collect more poses there."]
    if v.status == CONDITIONAL:
        return [f"With the conditions resolved, sign below and put {v.model} into service (cellcal export-urdf, "
                "compensate-job or export-targets with this model)."]
    return [f"Sign below and put {v.model} into service (cellcal export-urdf, compensate-job or export-targets with "
            "this model)."]


@dataclass(frozen=True)
class Remedy:
    """What to do about one kind of condition: the warnings it answers (a regular expression), the step, and the
    command the step names (a step the command already gives, as evaluate's top-up, is not repeated)."""

    kind: str
    pattern: str
    command: str
    step: str


#: One remedy per kind of warning a command gives (:mod:`app.reports.command_warnings`), in the order shown.
REMEDIES = (
    Remedy("extrapolation", r"outside the joint range|beyond the .* training data|outside the \(q2, q3\) region",
           "cellcal select",
           "The model extrapolates beyond the poses it was trained on: collect poses that cover the task and refit "
           "(cellcal select --robot ROBOT --data CANDIDATES.csv --given TRAIN.csv --task TASK.csv --poses 21 --out "
           "topup.csv, measure them with cellcal collect, then cellcal fit with --add topup.csv)."),
    Remedy("unseen directions", r"parameter directions", "cellcal plan",
           "The training poses leave parameter directions unseen: plan poses that see them all (cellcal plan --robot "
           "ROBOT --design optimal --out plan.json), measure them (cellcal collect) and refit."),
    Remedy("instability", r"may be unstable", "--method pi",
           "An interpolated model may be unstable between its anchors: put the pi model into service instead (cellcal "
           "fit --method pi), or train on more clusters (a denser plan) and refit."),
    Remedy("frames", r"off by a frame", "cellcal register",
           "A frame of the cell is off, not the kinematics: register the cell again (cellcal register --robot ROBOT) "
           "so that the cell file holds the measured base and tool frames, then evaluate again."),
    Remedy("outliers", r"gross measurement errors|gross-error bound", "remeasure",
           "Training rows were set aside as gross errors: check the markers of the rows named (a swap, a wrong rigid "
           "body), remeasure those poses and refit."),
    Remedy("measurement shift", r"jumps by .* along one direction", "mocap calibration",
           "The recording holds a measurement jump: check the mocap calibration of that session and remeasure the "
           "shifted poses."),
)


def _remedies(conditions: Sequence[str]) -> list[Remedy]:
    return [r for r in REMEDIES if any(re.search(r.pattern, c) for c in conditions)]


def condition_steps(conditions: Sequence[str], said: str = "") -> list[str]:
    """The remedy of each kind of condition among ``conditions``, once per kind, except those whose command ``said``
    (the steps given already) names; one closing step for the conditions no remedy answers."""
    steps = [r.step for r in _remedies(conditions) if r.command not in said]
    other = [c for c in conditions if not _remedies([c])]
    if other:
        steps.append(f"For the other condition{'s' if len(other) > 1 else ''} listed, resolve "
                     f"{'each' if len(other) > 1 else 'it'} or state on this page why it does not matter for this "
                     "cell.")
    return steps


def next_steps(v: Verdict, given: Sequence[str]) -> list[str]:
    """The next steps of a verdict: ``given`` (the command's own steps) or the default one, and under conditions,
    first, what to do about each of them (:func:`condition_steps`): recalibrate's "sign below" followed the
    conditions without a word about them."""
    steps = list(given) or default_next_steps(v)
    if v.status != CONDITIONAL:
        return steps
    return condition_steps(v.conditions, " ".join(given)) + steps
