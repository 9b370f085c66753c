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
from typing import Final, Literal

from ncmeasure.analysis.judgement.diagnosis import FLAT_THRESHOLD_PERCENT, NOT_IDENTIFIABLE_TEXT
from ncmeasure.formats.results import AxisResult, PositionDependency, Verdict

__all__ = [
    "FAULT_SPREAD_PERCENT",
    "MIN_WINDOW_SHARE",
    "axis_verdict",
    "comparison_verdict",
    "percent_text",
]

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
    verdict: Verdict, status: Literal["ok", "warning", "critical"], change: str
) -> Verdict:
    """The verdict with a comparison against a reference: the worse of both, comparison first.

    Args:
        verdict: The axis' own verdict.
        status: The comparison's status for the axis.
        change: The change against the reference, in words (for the reason).
    """
    if status == "critical":
        return Verdict(
            level="fault",
            reason=f"Against the reference: {change}, beyond the critical limit.",
            action=verdict.action
            if verdict.level == "fault"
            else "Find the cause of the change before the machine is shipped or used again.",
        )
    if status == "warning" and verdict.level == "ok":
        return Verdict(
            level="check",
            reason=f"Against the reference: {change}, beyond the warning limit.",
            action="Measure again to confirm the change; if it repeats, look for its cause.",
        )
    if status == "ok" and verdict.level == "ok":
        return Verdict(
            level="ok",
            reason=f"Against the reference: {change}, within the limits. {verdict.reason}",
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
