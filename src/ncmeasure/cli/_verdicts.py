"""Verdicts, changes and warnings on the console: what analyze, compare and demo print."""

from collections.abc import Mapping
from typing import TYPE_CHECKING

from ncmeasure.cli._app import console

if TYPE_CHECKING:
    from rich.text import Text

    from ncmeasure.analysis.judgement.summary import AxisComparison, Headline
    from ncmeasure.formats.comparison import Comparison
    from ncmeasure.formats.results import Results

LEVEL_STYLE = {"ok": "bold green", "check": "bold yellow", "fault": "bold red"}


def verdict_line(name: str, headline: "Headline") -> "Text":
    """``axis X: fault · Coulomb friction 1.58 Nm (...); spread ...; why; what to do``.

    The Coulomb figure is :attr:`Headline.coulomb_text`, the report's headline.
    """
    from rich.text import Text

    verdict = headline.verdict
    line = Text(f"axis {name}: ")
    line.append(verdict.level, style=LEVEL_STYLE.get(verdict.level, "bold"))
    line.append(
        f" · Coulomb friction {headline.coulomb_text}; {headline.travel_text}. {verdict.reason}"
    )
    if verdict.level != "ok":
        action = verdict.action.rstrip(".")
        line.append(f" What to do: {action[:1].upper()}{action[1:]}.")
    return line


def verdict_text(verdicts: Mapping[str, str]) -> "Text":
    """``X ok Z fault``, each level in its colour (the store's tables)."""
    from rich.text import Text

    text = Text()
    for index, (axis, level) in enumerate(verdicts.items()):
        if index:
            text.append(" ")
        text.append(f"{axis} ")
        text.append(level, style=LEVEL_STYLE.get(level, "bold"))
    return text


def print_verdicts(
    results: "Results", comparison: "Comparison | None" = None, indent: str = ""
) -> None:
    """One line per analysed axis, verdict first; then the axes not analysed and why.

    With a comparison, the verdict is combined with the axis' change against
    its base (the last compared run's, as the report shows it).
    """
    for name in results.axes:
        print_verdict(results, name, comparison, indent)
    print_skipped(results, indent)


def print_verdict(
    results: "Results", name: str, comparison: "Comparison | None" = None, indent: str = ""
) -> None:
    """The verdict line of one axis, with its change against the comparison's base."""
    from rich.text import Text

    from ncmeasure.analysis.judgement.summary import axis_comparison, axis_headline

    against = axis_comparison(comparison, name) if comparison is not None else None
    headline = axis_headline(results.axes[name], against)
    line = Text(indent).append_text(verdict_line(name, headline))
    if against is not None:
        append_change(line, headline, against)
    console().print(line)


def append_change(line: "Text", headline: "Headline", against: "AxisComparison") -> None:
    """The change against the base and its likely cause, unless the verdict says them already."""
    from ncmeasure.analysis.judgement.verdict import names_change_cause
    from ncmeasure.report.words import CAUSE_TITLES

    if against.change not in headline.verdict.reason:
        line.append(f" Against {against.base!r}: {against.status}, {against.change}.")
    named = names_change_cause(against.limit_status or against.status, against.diagnosis)
    if against.cause is not None and against.cause.cause != "none" and not named:
        title = CAUSE_TITLES.get(against.cause.cause, against.cause.cause)
        line.append(f" Likely cause of the change: {title} (score {against.cause.score:.2f}).")


def print_skipped(results: "Results", indent: str = "") -> None:
    """One line per axis not analysed, with the reason."""
    from rich.text import Text

    for name, reason in results.skipped.items():
        line = Text(f"{indent}axis {name}: ")
        line.append("not analysed", style="bold")
        line.append(f" · {reason}")
        console().print(line)


def print_warnings(results: "Results") -> None:
    """Analysis warnings on stderr; one shared by every axis once.

    The recording's own problems (a torn tail, missing samples) are not repeated
    here: the reader logs each as it reads the recording, before the results.
    """
    from rich.text import Text

    lists = [axis.warnings for axis in results.axes.values()]
    shared = set.intersection(*(set(w) for w in lists)) if len(lists) > 1 else set()
    for warning in lists[0] if lists else []:
        if warning in shared:
            console(stderr=True).print(Text.assemble(("warning:", "yellow"), f" {warning}"))
    for name, axis in results.axes.items():
        for warning in axis.warnings:
            if warning not in shared:
                console(stderr=True).print(
                    Text.assemble(("warning:", "yellow"), f" axis {name}: {warning}")
                )


def print_comparison(comparison: "Comparison", runs: "list[Results]") -> None:
    """Per compared run and axis: its verdict with the change, the report's headline figure."""
    from rich.text import Text

    from ncmeasure.analysis.judgement.summary import axis_comparison, axis_headline, format_number

    for label, results in zip(comparison.others, runs, strict=True):
        for name, axis in results.axes.items():
            against = axis_comparison(comparison, name, label)
            headline = axis_headline(axis, against)
            line = Text(f"{label}: ").append_text(verdict_line(name, headline))
            if against is None:
                line.append(f" Not compared with {comparison.base}.")
            else:
                append_change(line, headline, against)
            console().print(line)
        for name, reason in results.skipped.items():
            console().print(Text(f"{label}: axis {name}: not analysed · {reason}"))
    for fleet in comparison.fleet:
        outliers = ", ".join(fleet.outliers) or "none"
        console().print(
            Text(
                f"fleet, axis {fleet.axis}: mean friction {format_number(fleet.mean)} "
                f"{fleet.unit} over {len(fleet.runs)} runs, spread {fleet.spread_percent:.1f} %, "
                f"outliers: {outliers}"
            )
        )
    if comparison.problems:
        console().print(
            f"{len(comparison.problems)} matching problem(s): not every point was compared "
            "(the comparison file and the report list them)"
        )
