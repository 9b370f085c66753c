"""NC programs: dialects, rendering through templates, and the program reader and checker.

``generate_programs(config)`` plans (and refuses a plan beyond the machine
file's limits); its ``write(dir)`` renders the templates in a sandbox,
streaming into a staging folder, checks the result and moves it into place,
with schedule.json and the setup sheet for the technician (``setup.py``:
SETUP.md and setup.html).
``check_programs(dir)`` re-reads what was written, independently of the
templates, and holds it against the soft limits, the maximum feeds, the
schedule and the dialect's allowed codes.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ncmeasure.lazy import lazy_names

if TYPE_CHECKING:
    from ncmeasure.program.check import CheckReport, check_programs
    from ncmeasure.program.dialect import Dialect, available_dialects, load_dialect
    from ncmeasure.program.render import GeneratedPrograms, generate_programs

_LAZY = {
    "CheckReport": "ncmeasure.program.check",
    "check_programs": "ncmeasure.program.check",
    "Dialect": "ncmeasure.program.dialect",
    "available_dialects": "ncmeasure.program.dialect",
    "load_dialect": "ncmeasure.program.dialect",
    "GeneratedPrograms": "ncmeasure.program.render",
    "generate_programs": "ncmeasure.program.render",
}
"""The public names and their modules, imported on first use: ``ncmeasure controllers``
needs the dialects, not the planner and Jinja that rendering imports."""


__getattr__ = lazy_names(__name__, _LAZY, globals())


__all__ = [
    "CheckReport",
    "Dialect",
    "GeneratedPrograms",
    "available_dialects",
    "check_programs",
    "generate_programs",
    "load_dialect",
]
