"""The colours of ncmeasure's figures, in one place and without matplotlib.

The figures (SVG written directly: the report's, the dashboard's, the fleet report's
trends; and the trend PNG of :mod:`ncmeasure.report.plots`) draw with these, so a fault
is the same red on every page.
"""

from __future__ import annotations

from typing import Final

__all__ = [
    "CRITICAL",
    "GOOD",
    "GRID",
    "INK",
    "LINE",
    "PALETTE",
    "VERDICT_COLOURS",
    "WARNING",
]

PALETTE: Final = ("#1f5fa8", "#e07b00", "#2e8b3e", "#c0392b", "#7b4fa3", "#8c6d31", "#d45fa0")
"""One colour per measuring position (and the raw-data signals); distinct on screen and
paper."""
LINE: Final = PALETTE[0]
"""A single series' line."""
GOOD: Final = PALETTE[2]
"""Within the limits."""
WARNING: Final = PALETTE[1]
"""A warning, the warning band."""
CRITICAL: Final = PALETTE[3]
"""Critical, the critical band, a fault."""
INK: Final = "#222222"
"""Text."""
GRID: Final = "#d9d9d9"
"""Grid lines."""
VERDICT_COLOURS: Final = {"ok": GOOD, "check": "#d08a00", "fault": CRITICAL}
"""The marker colour of each verdict of an analysis (the pages' traffic lights, a shade
stronger)."""
