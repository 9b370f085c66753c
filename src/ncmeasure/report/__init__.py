"""The friction report: plots and one self-contained HTML page per analysis.

::

    from ncmeasure.report import write_report
    write_report(results, "report.html", recording=recording, windows=windows)

writes ``report.html`` (plots embedded as SVG, inline CSS, no scripts or external
resources; prints on A4) and the same plots as SVG files in ``report_plots/``.
For a recording read chunk by chunk, :class:`RawTraces` gathers the raw-data
figures' data while the analysis reads it (``analyze(..., on_windows=
traces.watch)``, then ``write_report(..., traces=traces.found)``), instead of
the report reading it again. The ``*_svg`` functions return a figure as SVG text,
for use elsewhere (no matplotlib is imported for them).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ncmeasure.lazy import lazy_names

if TYPE_CHECKING:
    from ncmeasure.report.bearings import BearingLayout, bearing_layout
    from ncmeasure.report.colours import PALETTE
    from ncmeasure.report.comparison_figure import comparison_svg
    from ncmeasure.report.friction_svg import curves_svg, travel_svg
    from ncmeasure.report.raw_svg import raw_data_svg
    from ncmeasure.report.traces import RawTraces
    from ncmeasure.report.windows import find_window_times, window_times
    from ncmeasure.report.write import ReportProgress, write_report

_LAZY = {
    "BearingLayout": "ncmeasure.report.bearings",
    "bearing_layout": "ncmeasure.report.bearings",
    "curves_svg": "ncmeasure.report.friction_svg",
    "travel_svg": "ncmeasure.report.friction_svg",
    "PALETTE": "ncmeasure.report.colours",
    "comparison_svg": "ncmeasure.report.comparison_figure",
    "raw_data_svg": "ncmeasure.report.raw_svg",
    "RawTraces": "ncmeasure.report.traces",
    "find_window_times": "ncmeasure.report.windows",
    "window_times": "ncmeasure.report.windows",
    "ReportProgress": "ncmeasure.report.write",
    "write_report": "ncmeasure.report.write",
}
"""The public names and their modules, imported on first use: a command that formats
a number with :mod:`ncmeasure.report.words` imports none of the report's figures."""


__getattr__ = lazy_names(__name__, _LAZY, globals())


__all__ = [
    "PALETTE",
    "BearingLayout",
    "RawTraces",
    "ReportProgress",
    "bearing_layout",
    "comparison_svg",
    "curves_svg",
    "find_window_times",
    "raw_data_svg",
    "travel_svg",
    "window_times",
    "write_report",
]
