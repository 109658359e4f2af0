"""The sign-off verdict of a report: the model one section puts into service, accepted, accepted with conditions or
not accepted against the tolerance, its conditions being every warning the run gave (:mod:`app.reports.page`
renders it at the top of the page)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

from app.reports.acceptance import Acceptance, Tolerance


class Judged(Protocol):
    """What a verdict reads of a report section (:class:`app.reports.page.Section`, which renders the verdict)."""

    title: str
    acceptance: Sequence[Acceptance]
    acceptance_data: str
    conditions: Sequence[str]

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
        return ["Resolve each condition listed (or state why it does not matter for this cell) before signing; "
                f"then put {v.model} into service (cellcal export-urdf, compensate-job or export-targets with this "
                "model)."]
    return [f"Sign below and put {v.model} into service (cellcal export-urdf, compensate-job or export-targets with "
            "this model)."]
