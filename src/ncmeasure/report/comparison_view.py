"""The comparison section of the report page: changes per axis, runs, positions, the fleet.

The part of :func:`~ncmeasure.report.page.page_view` that turns a
comparison into its :class:`~ncmeasure.report.view.ComparisonView`: an
ncmeasure :class:`~ncmeasure.analysis.judgement.compare.Comparison` in full, any other
comparison model as its summary, findings and a table of the rest.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

from pydantic import BaseModel

from ncmeasure.analysis.judgement.summary import axis_comparison
from ncmeasure.formats.comparison import Comparison, GroupDeviation
from ncmeasure.report.view import (
    ComparisonPart,
    ComparisonView,
    Fact,
    Figure,
    Folded,
    Table,
    cell,
    embed_image,
    make_table,
    number_cell,
    numbered_position,
)
from ncmeasure.report.words import CAUSE_TITLES, format_date, format_number

__all__ = ["generic_comparison", "known_comparison", "value_text"]


def value_text(value: Any) -> str:
    """A value as the page shows it: numbers formatted, structures as JSON cut at 400 characters."""
    if isinstance(value, float):
        return format_number(value)
    if isinstance(value, BaseModel):
        value = value.model_dump(mode="json")
    if isinstance(value, dict | list | tuple):
        text = json.dumps(value, ensure_ascii=False, default=str)
        return text if len(text) <= 400 else text[:400] + " …"
    return "–" if value is None else str(value)


def _model_table(model: BaseModel, skip: Sequence[str] = ()) -> Table | None:
    rows = [
        [cell(name.replace("_", " ")), cell(value_text(getattr(model, name)))]
        for name in type(model).model_fields
        if name not in skip
    ]
    return make_table(["Item", "Value"], rows) if rows else None


def generic_comparison(comparison: BaseModel) -> ComparisonView:
    """Any other comparison model: its summary and findings first, the rest as a table."""
    parts: list[ComparisonPart] = []
    summary = getattr(comparison, "summary", None)
    if isinstance(summary, str):
        parts.append(ComparisonPart(headline=summary))
    elif isinstance(summary, BaseModel):
        parts.append(ComparisonPart(table=_model_table(summary)))
    elif isinstance(summary, Sequence) and summary:
        parts.append(ComparisonPart(items=tuple(value_text(s) for s in summary)))
    findings = getattr(comparison, "findings", None)
    if isinstance(findings, Sequence) and not isinstance(findings, str) and findings:
        models = [f for f in findings if isinstance(f, BaseModel)]
        if models and len(models) == len(findings):
            columns: list[str] = []
            for found in models:
                columns.extend(n for n in type(found).model_fields if n not in columns)
            table = make_table(
                [c.replace("_", " ") for c in columns],
                [[cell(value_text(getattr(m, c, None))) for c in columns] for m in models],
            )
            parts.append(ComparisonPart(heading="Findings", table=table))
        else:
            parts.append(
                ComparisonPart(heading="Findings", items=tuple(value_text(f) for f in findings))
            )
    parts.append(
        ComparisonPart(heading="Details", table=_model_table(comparison, ("summary", "findings")))
    )
    return ComparisonView(intro=(), facts=(), parts=tuple(parts))


def _group_where(group: GroupDeviation) -> str:
    where = numbered_position(group.position_index, group.position_mm)
    return f"axis {group.axis}, {where}, {group.direction}"


_MAX_PROBLEMS = 15


def known_comparison(
    comparison: Comparison, figure: Figure | None, axes: Sequence[str]
) -> ComparisonView:
    """An ncmeasure comparison in full: per axis, per run, the plot, per position, the fleet."""
    intro, facts = _intro(comparison)
    parts = [
        part
        for part in (
            _axis_changes(comparison, axes),
            _runs(comparison),
            ComparisonPart(figure=embed_image(figure)) if figure is not None else None,
            _groups(comparison),
            *_fleet(comparison),
            _problems(comparison),
        )
        if part is not None
    ]
    return ComparisonView(intro=(intro,), facts=facts, parts=tuple(parts))


def _intro(comparison: Comparison) -> tuple[str, tuple[Fact, ...]]:
    """What was compared with what, and the limits."""
    limits = comparison.limits
    if comparison.mode == "lifetime":
        intro = (
            f"This machine against its earlier measurement {comparison.base!r}: how much "
            "friction changed at each position and direction."
        )
    else:
        intro = (
            f"Machines of one type against {comparison.base!r}: the change per position "
            "and direction, and the spread of the fleet."
        )
    facts = (
        Fact("Base", comparison.base),
        Fact("Compared", ", ".join(comparison.others)),
        Fact(
            "Limits",
            f"warning beyond ±{limits.warning_percent:g} %, critical beyond "
            f"±{limits.critical_percent:g} % (median change over the velocities)",
        ),
        Fact("Compared on", format_date(comparison.created_utc)),
    )
    return intro, facts


def _axis_changes(comparison: Comparison, axes: Sequence[str]) -> ComparisonPart | None:
    """The status and likely cause of each compared run's change, axis by axis."""
    rows = []
    names = list(dict.fromkeys([*axes, *(g.axis for g in comparison.groups)]))
    for label in comparison.others:
        for axis in names:
            found = axis_comparison(comparison, axis, label)
            if found is None:
                continue
            change = next(
                (c for c in comparison.changes if c.label == label and c.axis == axis), None
            )
            cause = change.causes[0] if change is not None and change.causes else None
            rows.append(
                [
                    cell(label),
                    cell(axis),
                    cell(found.status, status=found.status),
                    cell(found.change),
                    cell(
                        CAUSE_TITLES.get(cause.cause, cause.cause) if cause else "–",
                        strong=cause is not None,
                        note=f"{cause.evidence} (score {cause.score:.2f})" if cause else "",
                    ),
                ]
            )
    if not rows:
        return None
    return ComparisonPart(
        heading="Change per axis and likely cause",
        table=make_table(["Run", "Axis", "Status", "Change", "Likely cause of the change"], rows),
        note="The status is that of the change in the one rule of the status (the one "
        "store check applies): Coulomb friction and the spread along the travel against "
        "the limits (viscous friction is shown, not judged), and a local change along the "
        "travel, which names its likely cause (a warning, critical when large); the axis' "
        "own verdict is not part of it. The change is the mean and, where several points "
        "were compared, the largest at one position and direction. The cause comes from "
        "the ratio against the base per velocity and position, so the "
        "machine's own position dependency cancels; a change alike at every position "
        "beyond the warning limit is a global offset (preload, guide carriage, "
        "lubricant).",
    )


def _runs(comparison: Comparison) -> ComparisonPart | None:
    """One row per compared run: its largest change and where."""
    if not comparison.runs:
        return None
    run_rows = []
    for run in comparison.runs:
        groups = [g for g in comparison.groups if g.label == run.label]
        worst = max(groups, key=lambda g: abs(g.median_deviation_percent), default=None)
        where = (
            f"{_group_where(worst)}: {worst.median_deviation_percent:+.1f} %"
            if worst is not None
            else "–"
        )
        run_rows.append(
            [
                cell(run.label),
                cell(run.machine or "–"),
                number_cell(run.points),
                number_cell(f"{run.max_abs_deviation_percent:.1f} %"),
                cell(where),
                cell(run.status, status=run.status),
            ]
        )
    return ComparisonPart(
        heading="Runs",
        table=make_table(
            [
                "Run",
                "Machine",
                cell("Points", numeric=True),
                cell("Largest change", numeric=True),
                "Where",
                "Status",
            ],
            run_rows,
        ),
    )


def _groups(comparison: Comparison) -> ComparisonPart | None:
    """The change per run, axis, position and direction."""
    if not comparison.groups:
        return None
    group_rows = [
        [
            cell(group.label),
            cell(group.axis),
            cell(numbered_position(group.position_index, group.position_mm)),
            cell(group.direction),
            number_cell(group.points),
            number_cell(f"{group.median_deviation_percent:+.1f} %"),
            number_cell(f"{group.max_abs_point_deviation_percent:.1f} %"),
            cell(group.status, status=group.status),
        ]
        for group in comparison.groups
    ]
    return ComparisonPart(
        heading="Change per position and direction",
        table=make_table(
            [
                "Run",
                "Axis",
                "Position",
                "Direction",
                cell("Velocities", numeric=True),
                cell("Median change", numeric=True),
                cell("Largest single change", numeric=True),
                "Status",
            ],
            group_rows,
        ),
    )


def _fleet(comparison: Comparison) -> list[ComparisonPart]:
    """Per axis of a fleet comparison: each run's mean friction and how far it lies out."""
    parts = []
    for fleet in comparison.fleet:
        fleet_rows = [
            [
                cell(run),
                number_cell(f"{format_number(mean)} {fleet.unit}"),
                number_cell(f"{z:+.1f}"),
                cell("outlier" if run in fleet.outliers else ""),
            ]
            for run, mean, z in zip(fleet.runs, fleet.mean_friction, fleet.modified_z, strict=False)
        ]
        parts.append(
            ComparisonPart(
                heading=f"Fleet, axis {fleet.axis}",
                table=make_table(
                    [
                        "Run",
                        cell("Mean friction", numeric=True),
                        cell("Modified z-score", numeric=True),
                        "",
                    ],
                    fleet_rows,
                ),
                note=f"Mean {format_number(fleet.mean)} {fleet.unit}, spread "
                f"{fleet.spread_percent:.1f} % (max − min over the mean), standard deviation "
                f"{format_number(fleet.std)} {fleet.unit}, over {fleet.common_points} points "
                "measured in every run.",
            )
        )
    return parts


def _problems(comparison: Comparison) -> ComparisonPart | None:
    """What could not be compared, the first :data:`_MAX_PROBLEMS` of it, folded."""
    if not comparison.problems:
        return None
    shown = list(comparison.problems[:_MAX_PROBLEMS])
    if len(comparison.problems) > len(shown):
        shown.append(f"… and {len(comparison.problems) - len(shown)} more")
    return ComparisonPart(
        folded=Folded(summary=f"Not compared ({len(comparison.problems)})", items=tuple(shown))
    )
