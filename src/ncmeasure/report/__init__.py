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

from ncmeasure.report.bearings import BearingLayout, bearing_layout
from ncmeasure.report.friction_plots import plot_stribeck, plot_travel
from ncmeasure.report.plots import PALETTE, figure_png, plot_comparison, save_png
from ncmeasure.report.raw_plots import plot_raw_data
from ncmeasure.report.traces import RawTraces
from ncmeasure.report.windows import find_window_times, window_times
from ncmeasure.report.write import ReportProgress, write_report

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
