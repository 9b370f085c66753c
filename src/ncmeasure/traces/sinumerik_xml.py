"""Sinumerik Operate / SinuCom trace XML: servo signals of the NCK, read as a stream.

The layout, as verified against public parsers of real traces and a real
SINUMERIK 840D sl trace (``<traceSession version="01.00.03.02">``)::

    <traceSession version="...">
      <traceCaptureSetup_V20>                      newer traces; older ones and
        <collectionSettings .../>                  the same file again after the
        <sessionSettings sessionName="..."/>       V20 elements: <traceCaptureSetup>
        <sampleRateSettings servoSampleRate="0.002" .../>
        <signalSettings> <signal key="s1" name="..." unitsType="posn" .../> ...
        <triggerSettings> ... </triggerSettings>
      </traceCaptureSetup_V20>
      <traceDisplaySetup_V20> ... </traceDisplaySetup_V20>
      <traceCaptureSetup> ... </traceCaptureSetup>
      <traceDisplaySetup> ... </traceDisplaySetup>
      <traceData dataFrames="1">
        <dataFrame>
          <frameHeader startTime="..." startTriggerInc=".." stopTriggerInc=".."
                       stopInc=".." dropOuts="0"/>
          <dataSignal id="f1" key="s1" name="/Nck/!SD/nckServoDataActCurr64 [u1, 1]"
                      description="..." interval="0.002" datapointCount=".."  .../>
          ...
          <rec time="0" f1="1.25" f2="..."/>      one element per instant
          <rec time="0.002" f2="..."/>            a signal left out keeps its last value
        </dataFrame>
      </traceData>
    </traceSession>

* ``rec/@time`` is in seconds from the start of the trace; ``dataSignal/@interval``
  is the signal's sample period in seconds (a trace at 2 ms runs 0, 0.002, ...);
  ``rec`` attributes are named by ``dataSignal/@id`` (eliasrhoden/Trace-Tools
  ``tracetools.py``; the C# ``TraceSession.Import`` of a public TraceCompare tool,
  which lists the ``dataSignal`` and ``frameHeader`` attributes; a public
  checker of a 7199-record Sinumerik trace that verifies time, interval and
  the carrying forward of values a record leaves out).
* The setup elements before ``traceData`` are not needed to read the data; only
  ``sessionSettings/@sessionName`` is kept, from the first ``traceCaptureSetup*``
  element (``traceCaptureSetup_V20`` in the real 840D sl trace
  ``X_BK300_1.xml``, public in Yaaaaqing/mcep-cloud-edge-platform
  ``public/data/raw/``, which holds the V20 and the plain elements one after
  the other; ``traceCaptureSetup`` in the public ``SinumerikTraceHandler``).
* Signals sampled at different rates leave attributes out, and so does a signal
  whose value did not change (``X_BK300_1.xml``: a signal at 2 ms left out of
  913 of 7199 records while its value stood still); a left-out signal keeps its
  last value (the public ``SinumerikTraceHandler.read_decoded_xml``
  forward-fills; the checker above "inherits the previous value").
* An invalid sample holds the bit pattern of +inf read as an integer, about
  9.2188e18 (Trace-Tools treats every value above 9218868437227405000 as
  invalid). ncmeasure stores NaN until the next valid value and reports it.
* Signal names such as ``/Nck/!SD/nckServoDataActCurr64 [u1, 1]``: the number
  after ``u1`` is the axis index; the ``...32`` variants are the same signals
  in 32 bit. Meanings and units, as listed by a public importer of such
  traces (``ImportData``, German descriptions) and by the ``dataSignal``
  descriptions of ``X_BK300_1.xml``:
  ``nckServoDataActCurr64`` torque-generating actual current i(q) [A];
  ``nckServoDataActPos1stEnc64`` / ``...2ndEnc64`` actual position of measuring
  system 1 / 2 [mm]; ``nckServoDataActVelMot64`` actual motor speed [rpm, m/s
  for linear motors]; ``nckServoDataCmdTorque64`` torque setpoint [Nm];
  ``nckServoDataCtrlDev64`` control deviation [mm]; ``nckServoDataDrvLoad64``
  load m_set/m_set,limit [%].
* ``nckServoDataActVel1stEnc64`` / ``...2ndEnc64`` ("Velocity act. value meas.
  system 1 / 2", ``unitsType="velo"``) are mm/min: in ``X_BK300_1.xml`` each
  equals the change of the position of its measuring system over the 2 ms
  interval x 60 (backward difference) to within the rounding of the positions
  to 1e-6 mm (largest difference 0.029 mm/min, rounding bound 0.03 mm/min).
* The position setpoint is named after the measuring system it refers to:
  ``nckServoDataCmdPos2ndEnc64`` ("Position setpoint") in ``X_BK300_1.xml``,
  where it stays within 0.012 mm of ``ActPos2ndEnc64`` (-300 mm) while
  ``ActPos1stEnc64`` reads -1100.17 mm. The SINUMERIK Operate commissioning
  manual (service display axis/spindle) gives both actual positions in the
  machine coordinate system and "Active measuring system: 1 or 2". ncmeasure
  therefore takes position and velocity of an axis from the measuring system
  its command position names, else from measuring system 1, and never mixes
  the two (see :func:`sinumerik_candidates`).
* Not imported because the unit is not verified: ``nckServoDataCmdVelCtrlIn64``
  ("Velocity setpoint controller input", ``unitsType="velo"``). In
  ``X_BK300_1.xml`` it follows the slope of the position setpoint in mm/min
  (least-squares ratio 0.98, correlation 0.995), but no public document gives
  its unit (a speed controller setpoint may be in motor rpm), and it is not
  the commanded velocity alone: it reads -0.13 while the setpoint stands still.

The file is parsed with :func:`xml.etree.ElementTree.iterparse`; every element
(``rec`` or any other) is cleared and detached once read, so memory does not
grow with the trace, whatever it holds besides records.
"""

from __future__ import annotations

import datetime as dt
import logging
import math
import re
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import IO, Final

from ncmeasure.errors import RecordingError
from ncmeasure.formats.recording import RecordingMeta
from ncmeasure.traces.axes import Candidate, Mapped, Needs, plan_channels
from ncmeasure.traces.job import ImportJob
from ncmeasure.traces.merge import CarryForward
from ncmeasure.traces.text import PROGRESS_STEP_BYTES

__all__ = ["SinumerikSignal", "import_sinumerik_xml", "parse_signal_name", "sinumerik_candidates"]

log = logging.getLogger(__name__)

_READ_BYTES: Final = 1 << 16

#: ``/Nck/!SD/nckServoDataActCurr64 [u1, 1]``; also ``[u1; 1]`` and ``[u1  1]``
#: as CSV exports spell it, and a leading ``+`` some exports write.
_SIGNAL_NAME = re.compile(
    r"^\+?\s*(?P<path>[^\[\]]*?)(?P<var>[A-Za-z_][A-Za-z0-9_]*)\s*"
    r"\[\s*u(?P<unit>\d+)\s*(?:[,;]\s*|\s+)(?P<index>\d+)\s*\]\s*$"
)


@dataclass(frozen=True)
class SinumerikSignal:
    """A parsed Sinumerik signal name: the variable and the axis index."""

    name: str
    variable: str
    axis_index: int


def parse_signal_name(name: str) -> SinumerikSignal | None:
    """The variable and axis of ``/Nck/!SD/<variable> [u1, <axis>]``, or None."""
    match = _SIGNAL_NAME.match(name)
    if match is None:
        return None
    return SinumerikSignal(name.strip().lstrip("+").strip(), match["var"], int(match["index"]))


@dataclass(frozen=True)
class _Servo:
    """What an NCK servo signal becomes: its channel, conversion and measuring system."""

    signal: str
    conversion: str
    needs: Needs = ""
    #: 1 or 2 for a value of measuring system 1 or 2, 0 for none.
    system: int = 0
    #: Among the signals of one channel, lower wins; the 32-bit variant ranks one more.
    rank: int = 0


#: The servo signals ncmeasure imports, by variable without its ``64``/``32`` suffix (the
#: 64-bit variant wins over the 32-bit one). Position and velocity of the measuring
#: system that the command position refers to rank 0, those of the other system 2,
#: the motor speed (which needs the screw lead) 4; measured current wins over
#: current from torque.
_SERVO_SIGNALS: Final[Mapping[str, _Servo]] = {
    "nckServoDataActCurr": _Servo("current_a", "A, no conversion"),
    "nckServoDataCmdTorque": _Servo("current_a", "", needs="torque_constant", rank=10),
    "nckServoDataActPos1stEnc": _Servo(
        "position_mm", "mm of measuring system 1, no conversion", system=1
    ),
    "nckServoDataActPos2ndEnc": _Servo(
        "position_mm", "mm of measuring system 2, no conversion", system=2
    ),
    "nckServoDataActVel1stEnc": _Servo(
        "velocity_mm_min", "mm/min of measuring system 1, no conversion", system=1
    ),
    "nckServoDataActVel2ndEnc": _Servo(
        "velocity_mm_min", "mm/min of measuring system 2, no conversion", system=2
    ),
    "nckServoDataActVelMot": _Servo("velocity_mm_min", "", needs="screw_lead", rank=4),
}
_OTHER_SYSTEM_RANK: Final = 2

#: The position setpoint, named after the measuring system it refers to.
_COMMAND_POSITIONS: Final[Mapping[str, int]] = {
    "nckServoDataCmdPos1stEnc": 1,
    "nckServoDataCmdPos2ndEnc": 2,
}

#: Servo signals that are known but not imported, and why.
_NOT_IMPORTED: Final[Mapping[str, str]] = {
    "nckServoDataCmdPos1stEnc": (
        "position setpoint; ncmeasure records no command position: it tells which "
        "measuring system the axis is controlled on"
    ),
    "nckServoDataCmdPos2ndEnc": (
        "position setpoint; ncmeasure records no command position: it tells which "
        "measuring system the axis is controlled on"
    ),
    "nckServoDataCmdVelCtrlIn": (
        "velocity setpoint at the speed controller input: unit not verified (mm/min or "
        "motor rpm), so it does not become velocity_cmd_mm_min"
    ),
    "nckServoDataCtrlDev": "control deviation in mm: ncmeasure has no such signal",
    "nckServoDataDrvLoad": "drive load in % of the torque limit: ncmeasure has no such signal",
}

_WIDTH = re.compile(r"^(?P<stem>\w+?)(?P<bits>64|32)$")


def _stem(variable: str) -> tuple[str, int]:
    """``nckServoDataActCurr64`` -> (``nckServoDataActCurr``, 0), ``...32`` -> (..., 1).

    A name without the suffix gives ``("", 0)``: no servo signal that ncmeasure knows.
    """
    match = _WIDTH.match(variable)
    if match is None:
        return "", 0
    return match["stem"], 0 if match["bits"] == "64" else 1


@dataclass(frozen=True)
class _AxisSystems:
    """Which measuring system an axis' position and velocity come from, and why."""

    preferred: int
    reasons: Mapping[int, str]


def _axis_systems(signals: Sequence[SinumerikSignal]) -> dict[int, _AxisSystems]:
    """Per axis: the measuring system that the command position refers to, else system 1."""
    commands: dict[int, dict[int, str]] = {}
    for sig in signals:
        system = _COMMAND_POSITIONS.get(_stem(sig.variable)[0])
        if system is not None:
            commands.setdefault(sig.axis_index, {}).setdefault(system, sig.variable)
    result: dict[int, _AxisSystems] = {}
    for axis in {s.axis_index for s in signals}:
        found = commands.get(axis, {})
        if len(found) == 1:
            ((system, variable),) = found.items()
            other = 3 - system
            result[axis] = _AxisSystems(
                system,
                {
                    system: f"the command position {variable} refers to it",
                    other: (
                        f"the command position {variable} refers to measuring system "
                        f"{system}, of which the trace has no position or velocity; the "
                        "positions may be offset from machine coordinates"
                    ),
                },
            )
            continue
        if found:
            why = "the trace has command positions of both measuring systems"
        else:
            why = (
                "no command position (nckServoDataCmdPos1stEnc/2ndEnc) in the trace tells "
                "which measuring system the axis is controlled on"
            )
        result[axis] = _AxisSystems(
            1,
            {
                1: f"{why}; measuring system 1 by default",
                2: f"{why}, and it has no position or velocity of measuring system 1",
            },
        )
    return result


def sinumerik_candidates(names: Sequence[str], job: ImportJob) -> list[Candidate | None]:
    """A candidate for every signal name that ncmeasure uses, None (and a report line) else.

    Position and velocity candidates name their measuring system; those of the
    system that the axis' command position refers to (else system 1) rank first,
    so :func:`~ncmeasure.traces.axes.plan_channels` takes both from it.
    """
    parsed = [parse_signal_name(name) for name in names]
    systems = _axis_systems([p for p in parsed if p is not None])
    result: list[Candidate | None] = []
    for name, sig in zip(names, parsed, strict=True):
        if sig is None:
            job.note(f"{name}: not imported (not an axis signal of the form <name> [u1, <axis>])")
            result.append(None)
            continue
        stem, width_rank = _stem(sig.variable)
        known = _SERVO_SIGNALS.get(stem)
        if known is None:
            reason = _NOT_IMPORTED.get(stem, f"no ncmeasure signal for {sig.variable}")
            job.note(f"{sig.name}: not imported ({reason})")
            result.append(None)
            continue
        rank, system, why = known.rank + width_rank, "", ""
        if known.system:
            axis = systems[sig.axis_index]
            if known.system != axis.preferred:
                rank += _OTHER_SYSTEM_RANK
            system = f"measuring system {known.system}"
            why = axis.reasons[known.system]
        result.append(
            Candidate(
                source=sig.name,
                axis_id=str(sig.axis_index),
                signal=known.signal,
                needs=known.needs,
                rank=rank,
                conversion=known.conversion,
                measuring_system=system,
                measuring_system_reason=why,
            )
        )
    return result


class _CountingReader:
    """The trace file for iterparse, counting the bytes read for the progress callback."""

    def __init__(self, path: Path, job: ImportJob) -> None:
        self._file: IO[bytes] = path.open("rb")
        self._job = job
        self.bytes_read = 0
        self._reported = 0

    def read(self, size: int = -1) -> bytes:
        data = self._file.read(min(size, _READ_BYTES) if size and size > 0 else _READ_BYTES)
        self.bytes_read += len(data)
        if self.bytes_read - self._reported >= PROGRESS_STEP_BYTES or not data:
            self._job.tick(self.bytes_read)
            self._reported = self.bytes_read
        return data

    def __enter__(self) -> _CountingReader:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self._file.close()


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]


@dataclass
class _DataSignal:
    id: str
    name: str
    interval_s: float | None


class _TraceReader:
    """The state of one pass over the XML."""

    def __init__(self, job: ImportJob) -> None:
        self.job = job
        self.path = job.path
        self.signals: list[_DataSignal] = []
        self.frame_header: dict[str, str] = {}
        self.frames = 0
        self.recs = 0
        self.columns: list[tuple[str, int]] = []
        self.assembler: CarryForward | None = None
        self.unknown_attributes: set[str] = set()
        self.session_name: str | None = None
        self.known_ids: set[str] = set()

    def where(self, time_text: str | None = None) -> str:
        shown = f", time={time_text}" if time_text is not None else ""
        return f"{self.path}: <rec> #{self.recs + 1}{shown}"

    def data_signal(self, attrib: dict[str, str]) -> None:
        number = len(self.signals) + 1
        if self.assembler is not None:
            raise RecordingError(
                f"{self.path}: <dataSignal> #{number} comes after the first <rec>; "
                "a trace declares its signals first"
            )
        sid, name = attrib.get("id"), attrib.get("name")
        if not sid or not name:
            raise RecordingError(
                f"{self.path}: <dataSignal> #{number} has no id or no name attribute"
            )
        if any(s.id == sid for s in self.signals):
            raise RecordingError(f"{self.path}: <dataSignal> #{number}: id {sid!r} appears twice")
        interval: float | None = None
        try:
            interval = float(attrib.get("interval", ""))
        except ValueError:
            interval = None
        if interval is not None and not (math.isfinite(interval) and interval > 0):
            interval = None
        self.signals.append(_DataSignal(sid, name, interval))

    def start_assembler(self) -> None:
        if not self.signals:
            raise RecordingError(
                f"{self.path}: <rec> before any <dataSignal>: the trace declares no signals"
            )
        candidates = sinumerik_candidates([s.name for s in self.signals], self.job)
        pairs = [(s, c) for s, c in zip(self.signals, candidates, strict=True) if c is not None]
        mapped: list[Mapped] = plan_channels([c for _, c in pairs], self.job)
        column_of = {id(m.candidate): i for i, m in enumerate(mapped)}
        self.columns = [(s.id, column_of[id(c)]) for s, c in pairs if id(c) in column_of]
        intervals = [
            s.interval_s for s, c in pairs if id(c) in column_of and s.interval_s is not None
        ]
        period = min(intervals) if intervals else None
        start = _parse_start(self.frame_header.get("startTime"))
        if self.frame_header.get("startTime"):
            self.job.link["trace_start"] = self.frame_header["startTime"]
        if self.session_name:
            self.job.link["session"] = self.session_name
        sink = self.job.open_sink(
            [m.channel for m in mapped],
            nominal_period_s=period,
            start_utc=start,
            start_source="frameHeader startTime",
        )
        self.assembler = CarryForward(
            sink, [m.channel.name for m in mapped], [m.factor for m in mapped]
        )
        self.known_ids = {s.id for s in self.signals} | {"time"}

    def rec(self, attrib: dict[str, str]) -> None:
        if self.assembler is None:
            self.start_assembler()
        assembler = self.assembler
        assert assembler is not None
        time_text = attrib.get("time")
        if time_text is None:
            raise RecordingError(f"{self.where()}: no time attribute")
        try:
            time_s = float(time_text)
        except ValueError as exc:
            raise RecordingError(
                f"{self.where(time_text)}: time {time_text!r} is not a number"
                + (" (decimal comma?)" if "," in time_text else "")
            ) from exc
        for sid, column in self.columns:
            raw = attrib.get(sid)
            if raw is None:
                continue
            try:
                value = float(raw)
            except ValueError as exc:
                hint = " (a decimal comma; the XML uses decimal points)" if "," in raw else ""
                raise RecordingError(
                    f"{self.where(time_text)}: {sid}={raw!r} is not a number{hint}"
                ) from exc
            assembler.set(column, value, lambda: self.where(time_text))
        if len(attrib) > len(self.columns) + 1:
            for key in attrib:
                if key not in self.known_ids and key not in self.unknown_attributes:
                    self.unknown_attributes.add(key)
                    self.job.note(
                        f"{self.where(time_text)}: attribute {key!r} names no <dataSignal>; ignored"
                    )
        assembler.commit(time_s, lambda: self.where(time_text))
        self.recs += 1


def _parse_start(text: str | None) -> dt.datetime | None:
    """The trace start of ``frameHeader/@startTime`` (ISO 8601; without a time zone it is
    taken as UTC and the report says so); None when there is none or it does not parse."""
    if not text:
        return None
    try:
        return dt.datetime.fromisoformat(text.strip())
    except ValueError:
        return None


def import_sinumerik_xml(job: ImportJob) -> RecordingMeta:
    """Import a Sinumerik trace XML (see the module docstring).

    Raises:
        RecordingError: ``file: <element> #n: problem`` for a malformed or cut
            short XML, a record without time or with a time that does not
            increase, a value that is not a number, or no importable signal.
    """
    reader = _TraceReader(job)
    stack: list[ET.Element] = []
    try:
        with _CountingReader(job.path, job) as source:
            for event, elem in ET.iterparse(source, events=("start", "end")):
                tag = _local(elem.tag)
                if event == "start":
                    if not stack:
                        if tag != "traceSession":
                            raise RecordingError(
                                f"{job.path}: the root element is <{tag}>, not <traceSession>: "
                                "not a Sinumerik trace"
                            )
                        if elem.get("version"):
                            job.link["trace_version"] = elem.get("version")
                    stack.append(elem)
                    if tag == "dataFrame":
                        reader.frames += 1
                        if reader.frames > 1:
                            raise RecordingError(
                                f"{job.path}: a second <dataFrame>: ncmeasure imports traces "
                                "with one data frame (save each frame as its own trace)"
                            )
                    elif tag == "rec":
                        reader.rec(elem.attrib)
                    continue
                stack.pop()
                if tag == "dataSignal":
                    reader.data_signal(elem.attrib)
                elif tag == "frameHeader":
                    reader.frame_header = dict(elem.attrib)
                elif (
                    tag == "sessionSettings"
                    and reader.session_name is None
                    and _local(stack[-1].tag).startswith("traceCaptureSetup")
                ):
                    # traceCaptureSetup_V20 and traceCaptureSetup both hold it; the first wins
                    reader.session_name = elem.attrib.get("sessionName")
                # Every element, <rec> or any other, is read once it ends: freed and detached
                # then, so the tree never grows (the parent holds at most the child being read).
                elem.clear()
                if stack:
                    stack[-1].remove(elem)
    except ET.ParseError as exc:
        line, column = exc.position
        raise RecordingError(
            f"{job.path}:{line}:{column}: the XML is malformed or cut short ({exc}); "
            "nothing was imported"
        ) from exc
    assembler = reader.assembler
    if assembler is None:
        raise RecordingError(f"{job.path}: no <rec> element: the trace holds no samples")
    assembler.flush()
    missing = assembler.missing()
    if missing:
        raise RecordingError(
            f"{job.path}: {', '.join(missing)} never has a value in {reader.recs} records"
        )
    assembler.summarize(job, "records")
    return job.finish()
