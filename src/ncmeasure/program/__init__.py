"""NC programs: dialects, rendering through templates, and the program reader and checker.

``generate_programs(config)`` plans and renders; ``check_programs(dir)``
re-reads what was written, independently of the templates, and holds it
against the soft limits, the maximum feeds and the schedule.
"""

from ncmeasure.program.check import CheckReport, check_programs, load_schedule
from ncmeasure.program.dialect import Dialect, available_dialects, load_dialect
from ncmeasure.program.render import SCHEDULE_FILE, GeneratedPrograms, generate_programs

__all__ = [
    "SCHEDULE_FILE",
    "CheckReport",
    "Dialect",
    "GeneratedPrograms",
    "available_dialects",
    "check_programs",
    "generate_programs",
    "load_dialect",
    "load_schedule",
]
