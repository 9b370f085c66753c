"""The verdict per axis: ok, check or fault, with the reason in one sentence and what to do.

A technician must see in seconds whether a machine is fine. The verdict
reads the analysis of one axis (and the comparison against a reference,
where there is one) and says:

``fault``
    A clear assembly fault: friction changes along the travel by at least
    :data:`FAULT_SPREAD_PERCENT` in a pattern the diagnosis names (a bearing,
    the nut, a rail, a cover), significantly; or a comparison beyond its
    critical limit.
``check``
    Worth a look: a significant pattern along the travel between
    :data:`~ncmeasure.analysis.judgement.diagnosis.FLAT_THRESHOLD_PERCENT` and the
    fault threshold; a comparison beyond its warning limit; or a measurement
    that cannot show the assembly (fewer than 3 positions with data, gravity
    not separated on a vertical axis, a measuring position without a single
    window, fewer than :data:`MIN_WINDOW_SHARE` of the scheduled windows
    kept, or a layout where no two positions share a speed and a direction:
    position effects cannot be told from the speed dependence, and no cause
    is named).
``ok``
    Nothing of that: friction along the travel is flat or within the noise.

How well a model fits the curve is not part of the verdict: a Stribeck hump
is friction, not a fault, and the report states per curve which model
describes it. Nor are lost samples as such: they are counted and shown
(results.json, summary, report header); the verdict asks only whether what
was kept still covers the measurement.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final, Literal

from ncmeasure.analysis.judgement.diagnosis import FLAT_THRESHOLD_PERCENT, NOT_IDENTIFIABLE_TEXT
from ncmeasure.formats.comparison import AxisChange
from ncmeasure.formats.results import AxisResult, PositionDependency, Verdict

__all__ = [
    "FAULT_SPREAD_PERCENT",
    "LOCAL_SIGNATURES",
    "MIN_WINDOW_SHARE",
    "ChangeFigures",
    "axis_verdict",
    "cause_words",
    "comparison_verdict",
    "fingerprint_unchanged",
    "names_change_cause",
    "percent_text",
]

LOCAL_SIGNATURES: Final = frozenset(
    {"rising_to_loose_bearing", "rising_to_fixed_bearing", "high_at_both_ends", "step", "irregular"}
)
"""Patterns along the travel that point at a local cause (a bearing, the nut, a rail, a cover)."""

FAULT_SPREAD_PERCENT: Final = 15.0
"""A local pattern this strong is a fault: three times the flat threshold, three times the
few-percent repeatability of runs, below the ~20 % step of a sticking cover (method.md)."""

MIN_WINDOW_SHARE: Final = 0.5
"""Fewer than this share of the scheduled windows kept: the measurement should be repeated."""

_CAUSE_WORDS: Final = {
    "loose_bearing": "a shifted or tilted loose bearing",
    "fixed_bearing": "a shifted or tilted fixed bearing",
    "screw_nut": "a shifted or tilted ball-screw nut",
    "guide_rail": "a misaligned guide rail",
    "cover_or_seal": "a sticking cover, wiper seal or cable chain",
    "preload_or_carriage": "the preload of bearings or nut, or a guide carriage",
}

_CAUSE_ACTION: Final = {
    "loose_bearing": "check the alignment of the loose bearing to the nut and the rails",
    "fixed_bearing": "check the alignment of the fixed bearing to the nut and the rails",
    "screw_nut": "check the alignment of the ball-screw nut to the bearings",
    "guide_rail": "check the straightness and alignment of the guide rails",
    "cover_or_seal": "check the telescopic cover, wipers and cable chain where the step is",
    "preload_or_carriage": "check the preload of bearings and nut and the guide carriages",
}


@dataclass(frozen=True)
class ChangeFigures:
    """The diagnosis of an axis' change since its reference, in brief.

    What the judgement reads of a comparison's
    :class:`~ncmeasure.formats.comparison.AxisChange` (the ratio of the two
    measurements along the travel, the machine's own profile divided out); the
    store keeps the same figures per measurement.
    """

    signature: str
    """The pattern of the change along the travel."""
    cause: str
    """Its leading cause (``none`` when no change shows)."""
    spread_percent: float
    """How much the change varies along the travel, (max − min) / mean, %."""
    mean_percent: float
    """The mean change, %."""

    @classmethod
    def of(cls, change: AxisChange) -> ChangeFigures:
        """The figures of a comparison's change of one axis."""
        lead = change.causes[0].cause if change.causes else "none"
        return cls(change.signature, lead, change.spread_percent, change.mean_change_percent)

    @property
    def local(self) -> bool:
        """The change has a local pattern with a named cause (a bearing, the nut, ...)."""
        return self.signature in LOCAL_SIGNATURES and self.cause not in (
            "none",
            "preload_or_carriage",
        )

    @property
    def level(self) -> Literal["ok", "check", "fault"]:
        """What a local change alone means: ``fault`` from :data:`FAULT_SPREAD_PERCENT`,
        else ``check``; ``ok`` for a change without a local cause."""
        if not self.local:
            return "ok"
        return "fault" if self.spread_percent >= FAULT_SPREAD_PERCENT else "check"

    def cause_text(self) -> str:
        """The local change without its shape (for a sentence that has the shape already):
        ``a change of 2.8 % along the travel: likely a shifted or tilted loose bearing``."""
        return (
            f"a change of {percent_text(self.spread_percent)} along the travel: likely "
            f"{cause_words(self.cause, self.mean_percent)}"
        )

    def text(self) -> str:
        """The local change in words: ``friction changed along the travel by 2.8 % (rising
        towards the loose bearing): likely a shifted or tilted loose bearing``."""
        shape = _SHAPE_WORDS.get(self.signature, self.signature.replace("_", " "))
        return (
            f"friction changed along the travel by {percent_text(self.spread_percent)} "
            f"({shape}): likely {cause_words(self.cause, self.mean_percent)}"
        )


_SHAPE_WORDS: Final = {
    "rising_to_loose_bearing": "rising towards the loose bearing",
    "rising_to_fixed_bearing": "rising towards the fixed bearing",
    "high_at_both_ends": "largest at both ends",
    "step": "a step",
    "irregular": "irregular",
}


def cause_words(cause: str, mean_percent: float = 0.0) -> str:
    """A cause in words (a lower preload for a fall of a global change)."""
    if cause == "preload_or_carriage" and mean_percent < 0:
        return (
            "a preload loss of the ball-screw nut or the bearings, a guide carriage or "
            "the lubricant"
        )
    return _CAUSE_WORDS.get(cause, cause.replace("_", " "))


def fingerprint_unchanged(level: str, signature: str | None, change: ChangeFigures | None) -> bool:
    """An axis' own verdict comes from its pattern along the travel, and the comparison with
    its reference shows no change of it: the pattern is the machine's own fingerprint."""
    return (
        change is not None
        and change.signature == "flat"
        and level in ("check", "fault")
        and signature in LOCAL_SIGNATURES
    )


def names_change_cause(limit_status: str, diagnosis: ChangeFigures | None) -> bool:
    """Whether :func:`comparison_verdict` names the change's cause: a local change, or a
    cause of a change beyond a limit (preload, for a level that moved)."""
    return diagnosis is not None and (
        diagnosis.local or (diagnosis.cause != "none" and limit_status != "ok")
    )


def _significant(dependency: PositionDependency) -> bool:
    return dependency.signature not in ("flat", "insufficient_data") and bool(
        dependency.causes and dependency.causes[0].cause != "none"
    )


def axis_verdict(
    result: AxisResult,
    *,
    planned_windows: int | None = None,
    gap_share: float = 0.0,
    empty_positions: Sequence[float] = (),
) -> Verdict:
    """The verdict of one analysed axis (see the module for the rules).

    Args:
        result: The axis' results (its own ``verdict`` is ignored).
        planned_windows: Windows the schedule planned for the axis, when known.
        gap_share: Share of the recording's samples lost (named in the reason
            when the kept windows do not cover the measurement).
        empty_positions: Scheduled measuring positions (mm) without a window.
    """
    dependency = result.position_dependency
    if dependency is not None and _significant(dependency):
        cause = dependency.causes[0].cause
        words = _CAUSE_WORDS.get(cause, cause)
        spread = dependency.spread_percent
        text = (
            f"friction changes by {percent_text(spread)} along the travel "
            f"({dependency.signature.replace('_', ' ')}): likely {words}"
        )
        action = _CAUSE_ACTION.get(cause, "check the assembly of the axis")
        if spread >= FAULT_SPREAD_PERCENT:
            return Verdict(level="fault", reason=_sentence(text), action=_sentence(action))
        return Verdict(
            level="check",
            reason=f"A moderate pattern: {text}.",
            action="Compare it with this machine's reference measurement, if there is one "
            "(`ncmeasure compare`): the same pattern there is the machine's own fingerprint, "
            f"not a fault. Without one, measure again; if it repeats, {action}.",
        )
    concerns = _measurement_concerns(result, planned_windows, gap_share, empty_positions)
    if concerns:
        confounded = dependency is not None and not dependency.identifiable
        return Verdict(
            level="check",
            reason="The measurement cannot show the assembly fully: " + "; ".join(concerns) + ".",
            action="Measure every speed at the same positions, in both directions, to judge "
            "the travel."
            if confounded and len(concerns) == 1
            else "Measure again with the points named fixed.",
        )
    if dependency is None:
        spread_text = "one measuring position"
    else:
        spread_text = (
            f"friction varies by {percent_text(dependency.spread_percent)} along the travel"
        )
    return Verdict(
        level="ok",
        reason=f"No assembly fault shows: {spread_text}"
        + (
            f", within the {FLAT_THRESHOLD_PERCENT:g} % a healthy axis keeps"
            if dependency is not None and dependency.spread_percent < FLAT_THRESHOLD_PERCENT
            else ", within the noise"
            if dependency is not None
            else ""
        )
        + ".",
        action="None. Keep these results as the reference for later measurements "
        "(preload and carriage changes show only against a reference).",
    )


def _measurement_concerns(
    result: AxisResult,
    planned_windows: int | None,
    gap_share: float,
    empty_positions: Sequence[float],
) -> list[str]:
    concerns = []
    dependency = result.position_dependency
    positions = len(result.positions)
    if dependency is not None and not dependency.identifiable:
        concerns.append(NOT_IDENTIFIABLE_TEXT)
    elif dependency is None or dependency.signature == "insufficient_data":
        concerns.append(
            f"friction at {positions} measuring position(s) only, the pattern along the travel "
            "needs 3"
        )
    if result.vertical and result.offset is None:
        concerns.append("gravity is not separated from friction (one direction measured)")
    if empty_positions:
        listed = ", ".join(f"{x:g} mm" for x in empty_positions)
        concerns.append(f"no valid window at {listed}")
    if planned_windows and result.windows < MIN_WINDOW_SHARE * planned_windows:
        lost = f" ({gap_share * 100:.0f} % of the samples were lost)" if gap_share else ""
        concerns.append(
            f"only {result.windows} of the {planned_windows} scheduled windows were kept{lost}"
        )
    return concerns


_LEVELS: Final = ("ok", "check", "fault")
_STATUS_LEVEL: Final = {"ok": "ok", "warning": "check", "critical": "fault"}


def comparison_verdict(
    verdict: Verdict,
    status: Literal["ok", "warning", "critical"],
    change: str,
    *,
    signature: str | None = None,
    diagnosis: ChangeFigures | None = None,
    limit_status: Literal["ok", "warning", "critical"] | None = None,
) -> Verdict:
    """The verdict with a comparison against a reference: the change is judged, not the
    machine's own fingerprint.

    The level is the worse of the axis' own verdict and the change's status. An own
    verdict from a pattern along the travel that did not change (the change is flat) is
    the machine's fingerprint: a ``check`` becomes ``ok``, a ``fault`` a ``check`` (no
    change, but a pattern to confirm). The reason leads with what decides the level and
    names the change's cause where it has one; the other part follows.

    Args:
        verdict: The axis' own verdict.
        status: The change's status for the axis (the one rule,
            :func:`~ncmeasure.analysis.judgement.status.axis_status`: the limits and a local
            change along the travel).
        change: The change against the reference, in words.
        signature: The axis' own pattern along the travel.
        diagnosis: The diagnosis of the change, when there is one.
        limit_status: The characteristics against the limits alone (default: ``status``);
            a status from a local change alone says no limit was crossed.
    """
    limits = status if limit_status is None else limit_status
    unchanged = fingerprint_unchanged(verdict.level, signature, diagnosis)
    own = verdict.level
    if unchanged:
        own = "check" if verdict.level == "fault" else "ok"
    by_change = _STATUS_LEVEL[status]
    level = max(own, by_change, key=_LEVELS.index)
    limit_words = {
        "critical": ", beyond the critical limit",
        "warning": ", beyond the warning limit",
        "ok": ", within the limits",
    }[limits]
    # an ok verdict names no cause (a local change is at least a warning by the one rule)
    named = level != "ok" and names_change_cause(limits, diagnosis)
    cause = ""
    action: str | None = None
    if named and diagnosis is not None:
        cause = (
            f"; {diagnosis.cause_text()}"
            if diagnosis.local
            else f"; likely {cause_words(diagnosis.cause, diagnosis.mean_percent)}"
        )
        action = _CAUSE_ACTION.get(diagnosis.cause, "look for the cause of the change")
    against = f"Against the reference: {change}{limit_words}{cause}."
    own_text = verdict.reason[0].lower() + verdict.reason[1:].rstrip(".") if verdict.reason else ""
    if unchanged:
        fingerprint = (
            "The pattern along the travel was there in the reference as well: "
            + (
                "it is this machine's own fingerprint, not a change"
                if own == "ok"
                else "not a change, but as strong as a fault on its own; confirm it was "
                "accepted when the reference was measured"
            )
            + f" (on its own: {own_text})."
        )
        if level == "ok":
            return Verdict(
                level="ok",
                reason=f"{against} {fingerprint}",
                action="None. Keep comparing with the same reference.",
            )
        if _LEVELS.index(by_change) < _LEVELS.index(level):  # the pattern decides
            return Verdict(
                level=level,
                reason=f"{against} {fingerprint}",
                action="Compare the pattern with the reference's report; if it was not "
                "accepted then, " + verdict.action[0].lower() + verdict.action[1:]
                if verdict.action
                else "Compare the pattern with the reference's report.",
            )
    if level == "ok":
        return Verdict(level="ok", reason=f"{against} {verdict.reason}", action=verdict.action)
    if by_change == level:
        # the change decides: it leads, with its cause; the axis' own finding follows
        if level == "fault":
            what = (
                _sentence(action)
                if action
                else verdict.action
                if own == "fault"
                else "Find the cause of the change before the machine is shipped or used again."
            )
        else:
            what = (
                f"Measure again to confirm the change; if it repeats, {action}."
                if action
                else "Measure again to confirm the change; if it repeats, look for its cause."
            )
        same_cause = (
            diagnosis is not None
            and named
            and cause_words(diagnosis.cause, diagnosis.mean_percent) in verdict.reason
        )
        if unchanged:
            tail = f" {fingerprint}"
        else:
            tail = "" if own == "ok" or same_cause else f" On its own: {own_text}."
        return Verdict(level=level, reason=against + tail, action=what)
    # the axis' own finding decides; the change follows
    return Verdict(level=level, reason=f"{verdict.reason} {against}", action=verdict.action)


def _sentence(text: str) -> str:
    """``text`` with a capital first letter and a full stop."""
    text = text.strip()
    if not text:
        return text
    return text[0].upper() + text[1:] + ("" if text.endswith(".") else ".")


def percent_text(value: float) -> str:
    """A spread in %, with one decimal where it is small (0.6 %, not 0 %)."""
    return f"{value:.1f} %" if abs(value) < 10 else f"{value:.0f} %"
