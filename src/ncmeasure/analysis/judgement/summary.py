"""An axis at a glance: the one headline figure and verdict that every output shows.

The report's headline, ``ncmeasure analyze``'s console line and the demo's
summary all show the same quantity, computed here once:

- the **Coulomb friction** of the axis: per measuring position the mean of
  its directions' Coulomb friction (the Coulomb + viscous line fitted above
  the Stribeck region, with the axis' offset already taken out, so both
  directions are friction), then the mean over the positions and their
  range. A fit whose Coulomb friction is null (not determined by the data)
  is left out, never counted as zero;
- the **spread along the travel** and its pattern, from the position
  dependency;
- the **verdict** (:mod:`~ncmeasure.analysis.judgement.verdict`), combined with a
  comparison against a reference when there is one
  (:func:`~ncmeasure.analysis.judgement.verdict.comparison_verdict`).

:func:`axis_comparison` reads a :class:`~ncmeasure.analysis.judgement.compare.Comparison`
for one axis: its status (the worst of its positions and directions) and
the change in words, positions numbered as everywhere else (``position 2
(375 mm)``, the position index + 1).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final, Literal

from ncmeasure.analysis.judgement.compare import CHANGE_SHAPE
from ncmeasure.analysis.judgement.verdict import ChangeFigures, comparison_verdict, percent_text
from ncmeasure.formats.comparison import AxisChange, Comparison, GroupDeviation, worst_status
from ncmeasure.formats.results import AxisResult, Cause, Signature, Verdict

__all__ = [
    "SIGNATURE_WORDS",
    "AxisComparison",
    "Headline",
    "axis_comparison",
    "axis_headline",
    "format_number",
]

Status = Literal["ok", "warning", "critical"]

SIGNATURE_WORDS: Final[dict[Signature, str]] = {
    "flat": "flat",
    "rising_to_loose_bearing": "rising towards the loose bearing",
    "rising_to_fixed_bearing": "rising towards the fixed bearing",
    "high_at_both_ends": "high at both ends",
    "step": "a step",
    "irregular": "irregular",
    "insufficient_data": "too few positions to tell",
    "not_identifiable": "not separable from the speed dependence",
}
"""A few words per pattern along the travel."""


def format_number(value: float | None, digits: int = 3) -> str:
    """A number for a technician: about ``digits`` significant figures, no exponent.

    Args:
        value: The number; ``None`` or NaN give an en dash.
        digits: Significant figures for ordinary magnitudes.

    Returns:
        E.g. ``1.62``, ``12.4``, ``7500``, ``0.0123``; ``-`` signs as usual.
    """
    if value is None or not math.isfinite(value):
        return "–"
    if value == 0:
        return "0"
    magnitude = math.floor(math.log10(abs(value)))
    if magnitude >= digits - 1:
        return f"{value:.0f}"
    if magnitude < -4:
        return f"{value:.{digits - 1}e}"
    decimals = digits - 1 - magnitude
    return f"{value:.{decimals}f}"


@dataclass(frozen=True)
class AxisComparison:
    """One axis of one compared run against the base of a comparison.

    Attributes:
        axis: The axis name.
        label: The compared run.
        base: The base run.
        status: The status of the axis' change against the base (the one rule of
            :mod:`~ncmeasure.analysis.judgement.status`, without the axis' own verdict).
        change: The change in words, for a verdict's reason: e.g. ``friction
            +9.7 % on average, rising towards the loose bearing; at most
            +34.2 % at position 5 (745 mm), negative``.
        mean_change_percent: Mean change over the matched points (None when
            the comparison has no change diagnosis of the axis).
        worst: The position and direction with the largest median change.
        cause: The likely cause of the change, best first (None without a
            change diagnosis).
        diagnosis: The change diagnosis in brief, as the judgement reads it.
        limit_status: The characteristics' changes against the limits alone (None: not
            known, the status stands for it).
    """

    axis: str
    label: str
    base: str
    status: Status
    change: str
    mean_change_percent: float | None
    worst: GroupDeviation
    cause: Cause | None = None
    diagnosis: ChangeFigures | None = None
    limit_status: Status | None = None


def _where(group: GroupDeviation) -> str:
    return f"position {group.position_index + 1} ({group.position_mm:g} mm), {group.direction}"


def axis_comparison(
    comparison: Comparison, axis: str, label: str | None = None
) -> AxisComparison | None:
    """How one axis of a compared run changed against the base.

    Args:
        comparison: The comparison.
        axis: The axis.
        label: The compared run; default the last one (the run whose report
            ``ncmeasure compare --report`` and the demo write).

    Returns:
        The axis' status and change, or None when no point of the axis was compared.
    """
    run = label if label is not None else (comparison.others[-1] if comparison.others else None)
    groups = [g for g in comparison.groups if g.label == run and g.axis == axis]
    if run is None or not groups:
        return None
    summary = next((r for r in comparison.runs if r.label == run), None)
    status: Status = worst_status(g.status for g in groups)
    limit_status: Status | None = None
    if summary is not None and axis in summary.limit_status:
        limit_status = summary.limit_status[axis]
    if summary is not None and axis in summary.change_status:
        # the one rule's judgement of the change (judgement.status); the axis' own
        # verdict is combined with it by comparison_verdict, not counted twice
        status = summary.change_status[axis]
    worst = max(groups, key=lambda g: abs(g.median_deviation_percent))
    change: AxisChange | None = next(
        (c for c in comparison.changes if c.label == run and c.axis == axis), None
    )
    at_worst = f"{worst.median_deviation_percent:+.1f} % at {_where(worst)}"
    if change is not None:
        text = (
            f"friction {change.mean_change_percent:+.1f} % on average, "
            f"{CHANGE_SHAPE[change.signature]}; "
            + ("at most " if len(groups) > 1 else "")
            + at_worst
        )
        mean: float | None = change.mean_change_percent
    else:
        text = f"friction {at_worst}"
        mean = None
    return AxisComparison(
        axis=axis,
        label=run,
        base=comparison.base,
        status=status,
        change=text,
        mean_change_percent=mean,
        worst=worst,
        cause=change.causes[0] if change is not None and change.causes else None,
        diagnosis=ChangeFigures.of(change) if change is not None else None,
        limit_status=limit_status,
    )


@dataclass(frozen=True)
class Headline:
    """The figures of one axis at a glance (see the module for what each means).

    Attributes:
        verdict: The verdict; with a comparison, combined with it.
        own_verdict: The axis' verdict from its own measurement alone.
        unit: ``Nm`` or ``A`` (the axis' quantity).
        coulomb: Mean Coulomb friction over the positions (over the pooled fits where no
            position holds a line of its own); None when no fit determines it.
        coulomb_per_position: Per measuring position (in order), the mean of
            its directions, None where no direction has a value.
        position_numbers: The number of each measuring position (index + 1).
        curves: Curves (position × direction) whose Coulomb friction entered.
        curves_measured: Curves measured.
        viscous_per_m_min: Mean viscous friction per m/min over the same curves.
        spread_percent: Friction's spread along the travel, (max − min) / mean; None
            where the layout cannot tell it from the speed dependence.
        signature: Its pattern.
        against: The comparison of the axis, when there is one.
        pooled: Coulomb and viscous friction come from the positions pooled.
    """

    verdict: Verdict
    own_verdict: Verdict
    unit: Literal["Nm", "A"]
    coulomb: float | None
    coulomb_per_position: tuple[float | None, ...]
    position_numbers: tuple[int, ...]
    curves: int
    curves_measured: int
    viscous_per_m_min: float | None
    spread_percent: float | None
    signature: Signature | None
    against: AxisComparison | None = None
    pooled: bool = False

    @property
    def coulomb_range(self) -> tuple[float, float] | None:
        """Lowest and highest position's Coulomb friction, with two positions or more."""
        values = [v for v in self.coulomb_per_position if v is not None]
        return (min(values), max(values)) if len(values) > 1 else None

    @property
    def coulomb_text(self) -> str:
        """The headline figure: ``1.37 Nm (1.35–1.42 over 5 positions)``."""
        if self.coulomb is None:
            return "not determined"
        text = f"{format_number(self.coulomb)} {self.unit}"
        if self.pooled:
            return text + " (positions pooled)"
        bounds = self.coulomb_range
        if bounds is not None:
            positions = sum(v is not None for v in self.coulomb_per_position)
            text += (
                f" ({format_number(bounds[0])}–{format_number(bounds[1])} over "
                f"{positions} positions)"
            )
        return text

    @property
    def travel_text(self) -> str:
        """The spread along the travel: ``spread 21 % along the travel, rising towards ...``."""
        if self.signature == "not_identifiable":
            return "no profile along the travel (each speed at its own positions)"
        if self.spread_percent is None or self.signature is None:
            return "no profile along the travel"
        return (
            f"spread {percent_text(self.spread_percent)} along the travel, "
            f"{SIGNATURE_WORDS.get(self.signature, self.signature)}"
        )

    @property
    def viscous_text(self) -> str:
        """Mean viscous friction: ``0.26 Nm per m/min``."""
        if self.viscous_per_m_min is None:
            return "not determined"
        return f"{format_number(self.viscous_per_m_min)} {self.unit} per m/min"


def _mean(values: Sequence[float]) -> float | None:
    return sum(values) / len(values) if values else None


def axis_headline(result: AxisResult, against: AxisComparison | None = None) -> Headline:
    """The headline figures of one analysed axis.

    Args:
        result: The axis' results.
        against: The axis' comparison with a reference (:func:`axis_comparison`);
            its status and change enter the verdict.

    Returns:
        The headline; its ``coulomb_text`` is the figure the report and the
        console both print.
    """
    per_position: list[float | None] = []
    viscous: list[float] = []
    curves = measured = 0
    for position in result.positions:
        values = []
        for found in position.directions.values():
            if found is None:
                continue
            measured += 1
            fit = found.fit
            if fit is None or fit.coulomb is None or not math.isfinite(fit.coulomb):
                continue
            values.append(fit.coulomb)
            curves += 1
            if fit.viscous_per_mm_min is not None and math.isfinite(fit.viscous_per_mm_min):
                viscous.append(fit.viscous_per_mm_min * 1000.0)
        per_position.append(_mean(values))
    known = [v for v in per_position if v is not None]
    pooled: list[float] = []
    if not known and result.pooled is not None:
        # No position holds a line of its own: the positions pooled per direction.
        for found in result.pooled.directions.values():
            fit = None if found is None else found.fit
            if fit is None or fit.coulomb is None or not math.isfinite(fit.coulomb):
                continue
            pooled.append(fit.coulomb)
            if fit.viscous_per_mm_min is not None and math.isfinite(fit.viscous_per_mm_min):
                viscous.append(fit.viscous_per_mm_min * 1000.0)
    dependency = result.position_dependency
    identifiable = dependency is not None and dependency.identifiable
    verdict = result.verdict
    if against is not None:
        verdict = comparison_verdict(
            verdict,
            against.status,
            against.change,
            signature=dependency.signature if dependency is not None else None,
            diagnosis=against.diagnosis,
            limit_status=against.limit_status,
        )
    return Headline(
        verdict=verdict,
        own_verdict=result.verdict,
        unit=result.unit,
        coulomb=_mean(known) if known else _mean(pooled),
        coulomb_per_position=tuple(per_position),
        position_numbers=tuple(p.position_index + 1 for p in result.positions),
        curves=curves,
        curves_measured=measured,
        viscous_per_m_min=_mean(viscous),
        spread_percent=dependency.spread_percent if identifiable and dependency else None,
        signature=dependency.signature if dependency is not None else None,
        pooled=bool(pooled),
        against=against,
    )
