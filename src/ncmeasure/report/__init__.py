"""The friction report: plots and one self-contained HTML page per analysis.

::

    from ncmeasure.report import write_report
    write_report(results, "report.html", recording=recording, windows=windows)

writes ``report.html`` (plots embedded, inline CSS, no scripts or external
resources; prints on A4) and the same plots as PNGs in ``report_plots/``.
For a recording read chunk by chunk, :class:`RawTraces` gathers the raw-data
figures' data while the analysis reads it (``analyze(..., on_windows=
traces.watch)``, then ``write_report(..., traces=traces.found)``), instead of
the report reading it again. The ``plot_*`` functions return matplotlib
figures on their own Agg canvas, for use elsewhere; :func:`save_png` writes one.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ncmeasure.lazy import lazy_names

if TYPE_CHECKING:
    from ncmeasure.report.bearings import BearingLayout, bearing_layout
    from ncmeasure.report.colours import PALETTE
    from ncmeasure.report.friction_plots import plot_stribeck, plot_travel
    from ncmeasure.report.plots import figure_png, plot_comparison, save_png
    from ncmeasure.report.raw_plots import plot_raw_data
    from ncmeasure.report.traces import RawTraces
    from ncmeasure.report.windows import find_window_times, window_times
    from ncmeasure.report.write import ReportProgress, write_report

_LAZY = {
    "BearingLayout": "ncmeasure.report.bearings",
    "bearing_layout": "ncmeasure.report.bearings",
    "plot_stribeck": "ncmeasure.report.friction_plots",
    "plot_travel": "ncmeasure.report.friction_plots",
    "PALETTE": "ncmeasure.report.colours",
    "figure_png": "ncmeasure.report.plots",
    "plot_comparison": "ncmeasure.report.plots",
    "save_png": "ncmeasure.report.plots",
    "plot_raw_data": "ncmeasure.report.raw_plots",
    "RawTraces": "ncmeasure.report.traces",
    "find_window_times": "ncmeasure.report.windows",
    "window_times": "ncmeasure.report.windows",
    "ReportProgress": "ncmeasure.report.write",
    "write_report": "ncmeasure.report.write",
}
"""The public names and their modules, imported on first use: a command that formats
a number with :mod:`ncmeasure.report.words` imports no matplotlib."""


__getattr__ = lazy_names(__name__, _LAZY, globals())


__all__ = [
    "PALETTE",
    "BearingLayout",
    "RawTraces",
    "ReportProgress",
    "bearing_layout",
    "figure_png",
    "find_window_times",
    "plot_comparison",
    "plot_raw_data",
    "plot_stribeck",
    "plot_travel",
    "save_png",
    "window_times",
    "write_report",
]
