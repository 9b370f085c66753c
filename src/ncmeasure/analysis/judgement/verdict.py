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
            action=f"Measure again to confirm; if it repeats, {action}.",
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


def comparison_verdict(
    verdict: Verdict,
    status: Literal["ok", "warning", "critical"],
    change: str,
    *,
    signature: str | None = None,
    diagnosis: ChangeFigures | None = None,
) -> Verdict:
    """The verdict with a comparison against a reference: the change is judged, not the
    machine's own fingerprint.

    Args:
        verdict: The axis' own verdict.
        status: The comparison's status for the axis (the one rule,
            :func:`~ncmeasure.analysis.judgement.status.axis_status`: the change's
            limits and a local change's cause).
        change: The change against the reference, in words (for the reason).
        signature: The axis' own pattern along the travel.
        diagnosis: The diagnosis of the change, when there is one: its cause is named,
            and an own verdict from a pattern that did not change is lifted.
    """
    unchanged = fingerprint_unchanged(verdict.level, signature, diagnosis)
    own = "ok" if unchanged else verdict.level
    named = diagnosis is not None and (
        diagnosis.local or (diagnosis.cause != "none" and status != "ok")
    )
    why = ""
    if diagnosis is not None and diagnosis.local:
        why = f"; {diagnosis.text()}"
    elif named and diagnosis is not None:
        why = f"; likely {cause_words(diagnosis.cause, diagnosis.mean_percent)}"
    action = (
        _CAUSE_ACTION.get(diagnosis.cause, "look for the cause of the change")
        if named and diagnosis is not None
        else None
    )
    if status == "critical":
        return Verdict(
            level="fault",
            reason=f"Against the reference: {change}, beyond the critical limit{why}.",
            action=_sentence(action)
            if action
            else verdict.action
            if own == "fault"
            else "Find the cause of the change before the machine is shipped or used again.",
        )
    if status == "warning" and own == "ok":
        return Verdict(
            level="check",
            reason=f"Against the reference: {change}, beyond the warning limit{why}.",
            action=f"Measure again to confirm the change; if it repeats, {action}."
            if action
            else "Measure again to confirm the change; if it repeats, look for its cause.",
        )
    if status == "ok" and unchanged:
        return Verdict(
            level="ok",
            reason=f"Against the reference: {change}, within the limits. The pattern along "
            "the travel was there in the reference as well: it is this machine's own "
            f"fingerprint, not a change (on its own: {verdict.reason[0].lower()}"
            f"{verdict.reason[1:].rstrip('.')}).",
            action="None. Keep comparing with the same reference.",
        )
    if status == "ok" and own == "ok":
        return Verdict(
            level="ok",
            reason=f"Against the reference: {change}, within the limits{why}. {verdict.reason}",
            action=verdict.action,
        )
    return verdict


def _sentence(text: str) -> str:
    """``text`` with a capital first letter and a full stop."""
    text = text.strip()
    if not text:
        return text
    return text[0].upper() + text[1:] + ("" if text.endswith(".") else ".")


def percent_text(value: float) -> str:
    """A spread in %, with one decimal where it is small (0.6 %, not 0 %)."""
    return f"{value:.1f} %" if abs(value) < 10 else f"{value:.0f} %"
