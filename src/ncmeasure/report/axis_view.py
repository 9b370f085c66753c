"""One axis' section of the report page: verdict, facts, diagnosis, friction models, fits.

The part of :func:`~ncmeasure.report.page.page_view` that turns an axis'
results into its :class:`~ncmeasure.report.view.AxisView`.
"""

from __future__ import annotations

from typing import Final

from ncmeasure.analysis.judgement.summary import Headline
from ncmeasure.analysis.judgement.verdict import percent_text
from ncmeasure.formats.results import AxisResult, DirectionResult, LinearFit, NonlinearFit
from ncmeasure.report.curves import offset_is_significant
from ncmeasure.report.view import (
    LEVEL_TEXT,
    MODEL_NAMES,
    AxisSection,
    AxisView,
    Cell,
    Diagnosis,
    Fact,
    Folded,
    Offset,
    Table,
    cell,
    embed_image,
    make_table,
    number_cell,
    plural,
    position_text,
)
from ncmeasure.report.words import (
    CAUSE_CHECKS,
    CAUSE_TITLES,
    SIGNATURE_TEXT,
    format_number,
    format_with_error,
)

__all__ = ["axis_view"]


def _axis_notes(section: AxisSection) -> Folded | None:
    result = section.result
    # The warnings already say when the data is coarse and which values were left out.
    items = list(result.warnings)
    if result.velocity_quantum_mm_min > 0:
        items.append(
            f"the velocity is reported in steps of {format_number(result.velocity_quantum_mm_min)}"
            " mm/min"
        )
    if result.current_quantum_a > 0:
        items.append(
            f"the current is reported in steps of {format_number(result.current_quantum_a)} A"
        )
    if not items:
        return None
    return Folded(summary=f"Notes on axis {section.name} ({len(items)})", items=tuple(items))


def _diagnosis(section: AxisSection) -> Diagnosis | None:
    dependency = section.result.position_dependency
    if dependency is None:
        return None
    trend = dependency.trend_per_100mm
    if not dependency.identifiable:
        text = dependency.causes[0].evidence if dependency.causes else ""
        pattern = SIGNATURE_TEXT.get(dependency.signature, dependency.signature)
        return Diagnosis(pattern=pattern, text=text, causes=None)
    text = (
        f"Friction varies by {percent_text(dependency.spread_percent)} along the travel "
        f"(max − min relative to the mean); the trend is {trend:+.1f} % per 100 mm "
        "(positive: rising towards the max end). "
        f"Bearings: {section.bearings.describe()}."
    )
    causes = None
    if dependency.causes:
        causes = make_table(
            ["#", "Cause and what to check", cell("Likelihood", numeric=True), "Evidence"],
            [
                [
                    cell(rank),
                    cell(
                        CAUSE_TITLES.get(cause.cause, cause.cause),
                        strong=True,
                        note=CAUSE_CHECKS.get(cause.cause, ""),
                    ),
                    cell(
                        f"{cause.score * 100:.0f} %",
                        numeric=True,
                        bar_percent=round(max(0.0, min(1.0, cause.score)) * 100),
                    ),
                    cell(cause.evidence),
                ]
                for rank, cause in enumerate(dependency.causes, start=1)
            ],
        )
    return Diagnosis(
        pattern=SIGNATURE_TEXT.get(dependency.signature, dependency.signature),
        text=text,
        causes=causes,
    )


def _linear_cells(fit: LinearFit | None, points: int) -> list[Cell]:
    """Coulomb, viscous, |v| range and χ²ᵣ of the line; a null parameter shows its reason."""
    if fit is None:
        return [cell("no straight-line fit", muted=True, colspan=4, note=plural(points, "point"))]
    reason = fit.reason or "not determined by the points"
    cells: list[Cell] = []
    if fit.coulomb is None and fit.viscous_per_mm_min is None:
        cells.append(cell(reason, muted=True, colspan=2))
    else:
        cells.append(
            cell(reason, muted=True)
            if fit.coulomb is None
            else number_cell(format_with_error(fit.coulomb, fit.coulomb_stderr))
        )
        cells.append(
            cell(reason, muted=True)
            if fit.viscous_per_mm_min is None
            else number_cell(
                format_with_error(
                    fit.viscous_per_mm_min * 1000,
                    fit.viscous_stderr * 1000 if fit.viscous_stderr is not None else None,
                )
            )
        )
    low, high = fit.velocity_range_mm_min
    note = plural(fit.n_points, "point")
    if fit.points_below_range:
        note += f"; {fit.points_below_range} slower left out"
    cells.append(cell(f"{format_number(low)} – {format_number(high)}", numeric=True, note=note))
    cells.append(number_cell(format_number(fit.chi2_reduced)))
    return cells


def _models(result: AxisResult) -> Table | None:
    unit = result.unit
    rows = []
    for position in result.positions:
        for direction, found in sorted(position.directions.items()):
            if found is None:
                continue
            model = cell(
                MODEL_NAMES[found.model],
                strong=found.model is not None,
                muted=found.model is None,
                note=found.model_reason,
            )
            rows.append(
                [
                    cell(position_text(position)),
                    cell(direction),
                    model,
                    *_linear_cells(found.fit, len(found.points)),
                ]
            )
    if not rows:
        return None
    return make_table(
        [
            "Position",
            "Direction",
            "Model, and why",
            cell(f"Coulomb [{unit}]", numeric=True),
            cell(f"Viscous [{unit} per m/min]", numeric=True),
            cell("over |v| [mm/min]", numeric=True),
            cell("χ²ᵣ", numeric=True),
        ],
        rows,
    )


_MODELS_NOTE: Final = (
    "The model that describes the curve's points within their scatter: Coulomb + viscous "
    "friction (a straight line over speed), the Stribeck model (friction rising towards "
    "standstill) or the extended Stribeck model; 'none' when no model does. A Stribeck hump "
    "is friction, not a fault. Coulomb and viscous friction are those of the straight line, "
    "fitted by least squares over the speeds given (above the Stribeck region), ± one "
    "standard error, with the axis' offset taken out; χ²ᵣ is its reduced χ² (the line "
    "describes the points for χ²ᵣ below 10)."
)


def _parameter(fit: NonlinearFit, name: str, scale: float = 1.0) -> Cell:
    """A parameter as value ± half its 95 % interval, or a dash when the model lacks it."""
    if fit.parameters is None or name not in fit.parameters:
        return number_cell("–")
    value = fit.parameters[name] * scale
    interval = fit.ci95.get(name) if fit.ci95 is not None else None
    if interval is None:
        return number_cell(format_number(value))
    return number_cell(format_with_error(value, (interval[1] - interval[0]) / 2 * scale))


_NONLINEAR_PARAMETERS: Final = (
    ("T_C", 1.0),
    ("T_S", 1.0),
    ("v_S", 1.0),
    ("delta", 1.0),
    ("b", 1000.0),
    ("f_w", 1.0),
    ("k", 1.0),
)


def _nonlinear_fits(found: DirectionResult) -> list[NonlinearFit]:
    return [fit for fit in (found.stribeck, found.extended) if fit is not None]


def _nonlinear(result: AxisResult) -> Folded | None:
    unit = result.unit
    rows = []
    for position in result.positions:
        for direction, found in sorted(position.directions.items()):
            if found is None:
                continue
            for fit in _nonlinear_fits(found):
                name = MODEL_NAMES[fit.model]
                if fit.parameters is None:
                    values = [
                        cell(
                            fit.reason or "not identifiable",
                            muted=True,
                            colspan=len(_NONLINEAR_PARAMETERS),
                        )
                    ]
                    model = cell(name)
                else:
                    values = [_parameter(fit, p, scale) for p, scale in _NONLINEAR_PARAMETERS]
                    model = cell(
                        name,
                        note="" if fit.identifiable else f"not drawn: {fit.reason or 'uncertain'}",
                    )
                rows.append(
                    [
                        cell(position_text(position)),
                        cell(direction),
                        model,
                        *values,
                        number_cell(format_number(fit.chi2_reduced)),
                    ]
                )
    if not rows:
        return None
    table = make_table(
        [
            "Position",
            "Direction",
            "Model",
            cell(f"T_C [{unit}]", numeric=True),
            cell(f"T_S [{unit}]", numeric=True),
            cell("v_S [mm/min]", numeric=True),
            cell("δ", numeric=True),
            cell(f"b [{unit} per m/min]", numeric=True),
            cell(f"f_w [{unit}]", numeric=True),
            cell("k", numeric=True),
            cell("χ²ᵣ", numeric=True),
        ],
        rows,
        css="compact",
    )
    return Folded(
        summary=f"Stribeck model fits ({plural(len(rows), 'fit')})",
        table=table,
        note="Stribeck model T = T_C + (T_S − T_C)·exp(−(|v|/v_S)^δ) + b·|v| with T_C the "
        "Coulomb friction, T_S the static (breakaway) friction and v_S the Stribeck velocity; "
        "the extended model adds a rolling term f_w·(|v| / 1 m/min)^k. ± half the 95 % "
        "confidence interval. A fit the points do not determine shows why instead of "
        "parameters; only identifiable fits are drawn in the plot.",
        css="fits",
    )


def axis_view(section: AxisSection, headline: Headline) -> AxisView:
    """The axis' section: its verdict (``headline``), facts, plots, diagnosis and fits."""
    result = section.result
    verdict = headline.verdict
    positions = ", ".join(position_text(p) for p in result.positions) or "–"
    facts = (
        Fact("Quantity", "friction torque in Nm" if result.unit == "Nm" else "motor current in A"),
        Fact(
            "Torque constant",
            f"{result.torque_constant_nm_per_a:g} Nm/A"
            if result.torque_constant_nm_per_a is not None
            else "not known (values are motor current)",
        ),
        Fact("Positions", positions),
        Fact(
            "Windows", f"{result.windows} ({result.window_source}), {result.samples_used} samples"
        ),
        Fact("Bearings", section.bearings.describe()),
    )
    offset = None
    if result.offset is not None:
        offset = Offset(
            value=f"{format_with_error(result.offset.value, result.offset.stderr)} {result.unit}"
            + ("" if offset_is_significant(result.offset) else " (not significant)"),
            explanation=result.offset.explanation,
        )
    return AxisView(
        name=section.name,
        anchor=section.anchor,
        level=verdict.level,
        level_text=LEVEL_TEXT[verdict.level],
        reason=verdict.reason,
        action=verdict.action,
        coulomb=headline.coulomb_text,
        viscous=headline.viscous_text,
        travel=headline.travel_text,
        facts=facts,
        notes=_axis_notes(section),
        stribeck=embed_image(section.stribeck) if section.stribeck else None,
        travel_figure=embed_image(section.travel) if section.travel else None,
        diagnosis=_diagnosis(section),
        offset=offset,
        models=_models(result),
        models_note=_MODELS_NOTE,
        nonlinear=_nonlinear(result),
        raw=embed_image(section.raw) if section.raw else None,
        raw_note=section.raw_note or "",
    )
