"""ncmeasure: measure the friction of machine-tool feed axes with the machine's own drives.

The pipeline, one folder per stage, data flowing one way:

1. ``config``       a machine file (TOML) -> validated :class:`MachineConfig`
2. ``plan``         config -> :class:`Schedule`: velocity steps, positions, windows, timing
3. ``program``      schedule -> NC main program and one subprogram per axis, per
                    controller dialect (Jinja templates), and a reader that checks them
4. ``links``        drive links (CANopen CiA 402, Modbus TCP/RTU, replay) -> sample blocks
5. ``acquire``      a link -> a crash-safe ``recording`` on disk, until done
6. ``traces``       controller traces, CSV/MDF4 exchange and CAN logs -> recordings
7. ``analysis``     recordings -> friction, fits, diagnosis, comparison (results.json);
                    ``report`` -> HTML; ``compensation`` -> tables and offsets for controllers
8. ``store``        every fingerprint of every machine, in a database; ``web`` serves it
                    as a dashboard and a REST API, ``publish`` on the shop floor
9. ``sim``          the virtual machine and simulated drives; ``demo`` runs it all,
                    ``dryrun`` runs your own programs on it (both through ``virtual_run``)
10. ``cli``         the ``ncmeasure`` command

``formats`` holds the models of every file these stages write and read, at the
bottom. The layers, what travels between them, the threads and how to add a
register map, a dialect, a trace format or a link: ``docs/architecture.md``
(``lint-imports`` keeps the code to it).

The public API is re-exported here::

    from ncmeasure import load_machine, plan_machine, generate_programs
    config = load_machine("machine.toml")
    output = generate_programs(config)
    output.write("out/")
    result = record(config, duration_s=60, out="run1")   # the machine's [link]
    recording = read_recording("run1")
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ncmeasure._version import __version__
from ncmeasure.errors import (
    ConfigError,
    DialectError,
    NcMeasureError,
    OutputError,
    PlanError,
    ProgramCheckError,
    ProgramError,
)
from ncmeasure.lazy import lazy_names

if TYPE_CHECKING:
    from ncmeasure.acquire import record
    from ncmeasure.config import MachineConfig, config_hash, load_machine
    from ncmeasure.formats.schedule import Schedule
    from ncmeasure.plan import plan_machine
    from ncmeasure.program import GeneratedPrograms, check_programs, generate_programs
    from ncmeasure.recording import Recording, read_recording

_LAZY = {
    "record": "ncmeasure.acquire",
    "MachineConfig": "ncmeasure.config",
    "config_hash": "ncmeasure.config",
    "load_machine": "ncmeasure.config",
    "Schedule": "ncmeasure.formats.schedule",
    "plan_machine": "ncmeasure.plan",
    "GeneratedPrograms": "ncmeasure.program",
    "check_programs": "ncmeasure.program",
    "generate_programs": "ncmeasure.program",
    "Recording": "ncmeasure.recording",
    "read_recording": "ncmeasure.recording",
}
"""The public API's names and their modules, imported on first use: ``import ncmeasure``
(and so ``ncmeasure --version``) stays instant."""


__getattr__ = lazy_names(__name__, _LAZY, globals())


def __dir__() -> list[str]:
    return sorted(__all__)


__all__ = [
    "ConfigError",
    "DialectError",
    "GeneratedPrograms",
    "MachineConfig",
    "NcMeasureError",
    "OutputError",
    "PlanError",
    "ProgramCheckError",
    "ProgramError",
    "Recording",
    "Schedule",
    "__version__",
    "check_programs",
    "config_hash",
    "generate_programs",
    "load_machine",
    "plan_machine",
    "read_recording",
    "record",
]
