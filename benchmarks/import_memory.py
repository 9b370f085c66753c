"""Peak memory and throughput of ``ncmeasure import`` per trace format, against its floor.

For each format (TwinCAT Scope CSV, TNCscope, SINUMERIK trace CSV, SINUMERIK
trace XML with elements other than ``<rec>``, the generic CSV of ``ncmeasure
export``) it writes a synthetic trace of the chosen size in the layout the
importer reads (the layouts of the fixtures in ``tests/traces/fixtures``), then
runs ``ncmeasure import FILE -o DIR -q`` in a fresh interpreter per run, which
reports its own peak resident set size (``getrusage(RUSAGE_SELF).ru_maxrss``)
and the wall time of the command.

The baseline of the same run is the floor: the same command in a fresh
interpreter on a file of the same format a few kB long (every module
imported, nothing read). Floor and full import alternate, round by round; the
median and the range over the rounds are printed, the peak above the floor
against the goal (at most 300 MB for any input size), and the throughput in
MB of input per second over the floor's time (an import must stay linear in
the input: a quadratic one shows as a throughput that falls with the size).

The synthetic traces, per format (values cycle through a few thousand
plausible numbers; times run on at 1 ms or 2 ms):

* TwinCAT CSV: tab-separated with decimal commas, every channel with its own
  time column (the "All" layout of ``twincat_per_channel.csv``): X_current_a,
  X.ActVelo, Y_current_a at 1 ms, X.ActPos at 2 ms, which ends after half
  the rows (its cells hold a space then), so the merge holds one channel
  ahead of the others;
* TNCscope: curves v act., s actual, i ist at 3000 us and I nominal at
  6000 us (half the COUNT, then zeros as in ``tncscope.sco``);
* SINUMERIK CSV: a time column and six servo signals of two axes, the
  position of each axis left empty in every other row;
* SINUMERIK XML: the setup elements, a ``traceDisplaySetup`` with 5 % of the
  file in curve point elements, and a ``<marker>`` element (not ``<rec>``)
  every 500 records between the records of the data frame;
* generic CSV: ``time_s`` and three channels, as ``ncmeasure export`` writes.

Run:  python benchmarks/import_memory.py [--size-mb 500] [--rounds 3] [--formats ...]
      python benchmarks/import_memory.py --short     (a few MB: only checks that nothing crashes)
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, Final

MB: Final = 1_000_000
GOAL_MB: Final = 300.0
FLOOR_ROWS: Final = 200

#: Run in the child: the command line of ``ncmeasure``, then the peak RSS and the time.
_CHILD: Final = """
import json, resource, sys, time
result_path, *argv = sys.argv[1:]
sys.argv = ["ncmeasure", *argv]
from ncmeasure.cli import main
start = time.perf_counter()
code = 0
try:
    main()
except SystemExit as exc:
    code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
elapsed = time.perf_counter() - start
peak_kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
with open(result_path, "w") as file:
    json.dump({"code": code, "seconds": elapsed, "peak_bytes": peak_kib * 1024}, file)
"""


def _values(count: int, scale: float, decimals: int, comma: bool = False) -> list[str]:
    """``count`` plausible numbers (a slow sine with a ripple) as the trace would print them."""
    import math

    texts = []
    for k in range(count):
        phase = 2 * math.pi * k / count
        value = scale * (math.sin(phase) + 0.013 * math.cos(37 * phase))
        text = f"{value:.{decimals}f}"
        texts.append(text.replace(".", ",") if comma else text)
    return texts


def _write_rows(file: IO[str], rows: Iterator[str], size_bytes: int) -> int:
    """Write rows until the file reaches ``size_bytes``; the rows written."""
    written = file.tell()
    count = 0
    batch: list[str] = []
    for row in rows:
        batch.append(row)
        count += 1
        if len(batch) == 20_000:
            text = "".join(batch)
            file.write(text)
            written += len(text)
            batch.clear()
            if written >= size_bytes:
                break
    file.write("".join(batch))
    return count


def _rows_for(size_bytes: int, bytes_per_row: int) -> int:
    return max(FLOOR_ROWS, size_bytes // bytes_per_row)


def write_twincat(path: Path, size_bytes: int) -> None:
    """TwinCAT Scope CSV, "All" layout: a time column per channel, X.ActPos at 2 ms."""
    rows = _rows_for(size_bytes, 62)
    current = _values(4001, 3.0, 6, comma=True)
    velocity = _values(3001, 6000.0, 4, comma=True)
    position = _values(5003, 150.0, 6, comma=True)
    names = ("X_current_a", "X.ActVelo", "X.ActPos", "Y_current_a")
    sample_ms = ("1", "1", "2", "1")
    units = ("A (Ampere)", "(None)", "mm (Millimeter)", "A (Ampere)")
    with path.open("w", encoding="utf-8", newline="") as file:
        file.write(
            "Name\tfriction_xy\r\nFile\tC:\\TwinCAT\\Scope\\friction_xy.csv\r\n"
            "Starttime of export\t132959733843760000\tMontag, 2. Mai 2022\t15:56:24.376\r\n"
            "Endtime of export\t132959733853750000\tMontag, 2. Mai 2022\t15:56:25.375\r\n\r\n\r\n"
        )
        file.write("\t".join(f"Name\t{n}" for n in names) + "\r\n")
        for key, cells in (
            ("Data-Type", ("REAL64",) * 4),
            ("SampleTime[ms]", sample_ms),
            ("Offset", ("0",) * 4),
            ("ScaleFactor", ("1",) * 4),
            ("Unit", units),
        ):
            file.write("\t".join(f"{key}\t{c}" for c in cells) + "\r\n")
        file.write("\r\n")
        half = rows // 2

        def lines() -> Iterator[str]:
            for k in range(rows):
                pos = f"{2 * k}\t{position[k % 5003]}" if k < half else " \t "
                yield (
                    f"{k}\t{current[k % 4001]}\t{k}\t{velocity[k % 3001]}\t{pos}\t"
                    f"{k}\t{current[(k + 1000) % 4001]}\r\n"
                )

        _write_rows(file, lines(), size_bytes)


def write_tncscope(path: Path, size_bytes: int) -> None:
    """TNCscope text export: three curves at 3000 us, one at 6000 us (half the COUNT)."""
    rows = _rows_for(size_bytes, 40)
    velocity = _values(3001, 6000.0, 1)
    position = _values(5003, 150.0, 4)
    current = _values(4001, 3.0, 3)
    curves = (
        ("v act.", "mm/min", rows, 3000),
        ("s actual", "mm", rows, 3000),
        ("i ist", "A", rows, 3000),
        ("I nominal", "A", rows // 2, 6000),
    )
    with path.open("w", encoding="utf-8", newline="") as file:
        file.write("%[GLOBAL]\n%VERSION=synthetic, ncmeasure benchmark\n%DATE=06.05.2024\n%\n")
        for number, (kind, unit, count, cycle_us) in enumerate(curves, start=1):
            file.write(
                f"%[CURVE {number}]\n%CHANNELTYPE={kind}\n%AXISTYPE=X\n%DIMENSION={unit}\n"
                f"%COUNT={count}\n%CYCLETIME={cycle_us}\n%\n"
            )
        file.write("%[DATA]\n")
        half = rows // 2

        def lines() -> Iterator[str]:
            for k in range(rows):
                nominal = current[(k + 7) % 4001] if k < half else "0"
                yield (
                    f"{3000 * k};{velocity[k % 3001]};{position[k % 5003]};"
                    f"{current[k % 4001]};{nominal};\n"
                )

        _write_rows(file, lines(), size_bytes)


def write_sinumerik_csv(path: Path, size_bytes: int) -> None:
    """SINUMERIK trace CSV: time and six signals of two axes, positions every other row."""
    rows = _rows_for(size_bytes, 70)
    current = _values(4001, 3.0, 6)
    velocity = _values(3001, 6000.0, 6)
    position = _values(5003, 150.0, 6)
    signals = (
        "nckServoDataActCurr64 [u1; 1]",
        "nckServoDataActPos1stEnc64 [u1; 1]",
        "nckServoDataActVel1stEnc64 [u1; 1]",
        "nckServoDataActCurr64 [u1; 2]",
        "nckServoDataActPos1stEnc64 [u1; 2]",
        "nckServoDataActVel1stEnc64 [u1; 2]",
    )
    with path.open("w", encoding="utf-8", newline="") as file:
        file.write("time," + ",".join(f"+/Nck/!SD/{s}" for s in signals) + "\n")

        def lines() -> Iterator[str]:
            for k in range(rows):
                even = k % 2 == 0
                p1 = position[k % 5003] if even else ""
                p2 = position[(k + 99) % 5003] if even else ""
                yield (
                    f"{k / 500!r},{current[k % 4001]},{p1},{velocity[k % 3001]},"
                    f"{current[(k + 1) % 4001]},{p2},{velocity[(k + 5) % 3001]}\n"
                )

        _write_rows(file, lines(), size_bytes)


def write_sinumerik_xml(path: Path, size_bytes: int) -> None:
    """SINUMERIK trace XML with a display setup of curve points and markers between records."""
    rows = _rows_for(size_bytes, 110)
    current = _values(4001, 3.0, 6)
    velocity = _values(3001, 6000.0, 6)
    position = _values(5003, 150.0, 6)
    signals = (
        ("f1", "nckServoDataActCurr64 [u1, 1]"),
        ("f2", "nckServoDataActPos1stEnc64 [u1, 1]"),
        ("f3", "nckServoDataActVel1stEnc64 [u1, 1]"),
        ("f4", "nckServoDataCmdPos1stEnc64 [u1, 1]"),
    )
    with path.open("w", encoding="utf-8", newline="") as file:
        file.write(
            '<?xml version="1.0" encoding="utf-8" ?>\n<traceSession version="01.00.03.02">\n'
            "  <traceCaptureSetup_V20>\n"
            '    <sessionSettings sessionName="BENCH_X"/>\n'
            '    <sampleRateSettings servoSampleRate="0.002"/>\n'
            "  </traceCaptureSetup_V20>\n  <traceDisplaySetup_V20>\n"
        )
        points = max(10, size_bytes // 20 // 40)
        file.writelines(
            f'    <point curve="{k % 4}" x="{k}" y="{velocity[k % 3001]}"/>\n'
            for k in range(points)
        )
        file.write(
            '  </traceDisplaySetup_V20>\n  <traceData dataFrames="1">\n    <dataFrame>\n'
            '      <frameHeader startTime="2024-05-06T10:15:00+02:00" startTriggerInc="0" '
            'stopTriggerInc="0" stopInc="0" dropOuts="0"/>\n'
        )
        for sid, name in signals:
            file.write(
                f'      <dataSignal id="{sid}" key="k{sid}" name="/Nck/!SD/{name}" '
                'dataType="double" interval="0.002000"/>\n'
            )
        tail = "    </dataFrame>\n  </traceData>\n</traceSession>\n"

        def lines() -> Iterator[str]:
            for k in range(rows):
                pos = position[k % 5003]
                # a value that did not change is left out, as controllers do
                cmd = f' f4="{pos}"' if k % 3 else ""
                yield (
                    f'      <rec time="{k / 500:.6f}" f1="{current[k % 4001]}" f2="{pos}" '
                    f'f3="{velocity[k % 3001]}"{cmd}/>\n'
                )
                if k % 500 == 499:
                    yield f'      <marker time="{k / 500:.6f}" text="step {k // 500}"/>\n'

        _write_rows(file, lines(), size_bytes - len(tail))
        file.write(tail)


def write_generic_csv(path: Path, size_bytes: int) -> None:
    """The CSV of ``ncmeasure export``: time_s and three channels as shortest reprs."""
    rows = _rows_for(size_bytes, 60)
    current = [repr(float(v)) for v in _values(4001, 3.0, 6)]
    velocity = [repr(float(v)) for v in _values(3001, 6000.0, 4)]
    position = [repr(float(v)) for v in _values(5003, 150.0, 6)]
    with path.open("w", encoding="utf-8", newline="") as file:
        file.write("time_s,X_current_a,X_velocity_mm_min,X_position_mm\n")

        def lines() -> Iterator[str]:
            for k in range(rows):
                values = f"{current[k % 4001]},{velocity[k % 3001]},{position[k % 5003]}"
                yield f"{k / 1000!r},{values}\n"

        _write_rows(file, lines(), size_bytes)


#: format -> (file ending, writer, extra arguments of ``ncmeasure import``)
FORMATS: Final[dict[str, tuple[str, Callable[[Path, int], None], tuple[str, ...]]]] = {
    "twincat-csv": (".csv", write_twincat, ()),
    "tncscope": (".sco", write_tncscope, ()),
    "sinumerik-csv": (".csv", write_sinumerik_csv, ()),
    "sinumerik-xml": (".xml", write_sinumerik_xml, ()),
    "csv": (".csv", write_generic_csv, ()),
}


def _run(source: Path, fmt: str, extra: tuple[str, ...], work: Path) -> dict[str, float]:
    """One ``ncmeasure import`` in a fresh interpreter: its peak RSS and time."""
    # named after this process: two runs may share the inputs' folder
    output = work / f"recording-{os.getpid()}"
    shutil.rmtree(output, ignore_errors=True)
    result = work / f"child-{os.getpid()}.json"
    command = [sys.executable, "-c", _CHILD, str(result), "import", str(source)]
    command += ["-o", str(output), "-q", "--format", fmt, *extra]
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    outcome = json.loads(result.read_text()) if result.exists() else None
    result.unlink(missing_ok=True)
    shutil.rmtree(output, ignore_errors=True)
    if done.returncode or outcome is None or outcome["code"]:
        sys.exit(
            f"import of {source.name} ({fmt}) failed (exit {done.returncode}):\n"
            f"{done.stdout}{done.stderr}"
        )
    return {"seconds": outcome["seconds"], "peak_mb": outcome["peak_bytes"] / MB}


MIN_TIMED_S = 0.05
"""Seconds: an import this little longer than the floor's gets no rate (short mode's few MB)."""


def _spread(values: list[float]) -> str:
    return f"{statistics.median(values):8.1f} ({min(values):.1f}-{max(values):.1f})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size-mb", type=float, default=500.0, help="input size per format")
    parser.add_argument("--rounds", type=int, default=3, help="floor/import pairs per format")
    parser.add_argument("--formats", nargs="+", choices=list(FORMATS), default=list(FORMATS))
    parser.add_argument("--short", action="store_true", help="a few MB, one round: crash test")
    parser.add_argument(
        "--work", type=Path, default=None, help="keep the inputs here (reused when present)"
    )
    args = parser.parse_args()
    size_mb = 3.0 if args.short else args.size_mb
    rounds = 1 if args.short else args.rounds
    work = args.work or Path(tempfile.mkdtemp(prefix="ncmeasure-import-memory-"))
    work.mkdir(parents=True, exist_ok=True)
    print(
        f"ncmeasure import: peak RSS above the floor (a file of {FLOOR_ROWS} rows), "
        f"{rounds} round(s), median (range); goal <= {GOAL_MB:.0f} MB above the floor, any size"
    )
    print(f"python {sys.version.split()[0]}, {os.cpu_count()} cores")
    print(
        f"{'format':<14}{'input MB':>9}{'floor MB':>22}{'peak MB':>22}{'above floor':>22}"
        f"{'MB/s':>22}  goal"
    )
    failed = False
    try:
        for fmt in args.formats:
            ending, write, extra = FORMATS[fmt]
            source = work / f"{fmt}-{size_mb:g}MB{ending}"
            floor_source = work / f"{fmt}-floor{ending}"
            if not source.exists():
                write(source, int(size_mb * MB))
            if not floor_source.exists():
                write(floor_source, 0)
            floors: list[float] = []
            peaks: list[float] = []
            above: list[float] = []
            rates: list[float] = []
            input_mb = source.stat().st_size / MB
            for _ in range(rounds):
                floor = _run(floor_source, fmt, extra, work)
                full = _run(source, fmt, extra, work)
                floors.append(floor["peak_mb"])
                peaks.append(full["peak_mb"])
                above.append(full["peak_mb"] - floor["peak_mb"])
                import_s = full["seconds"] - floor["seconds"]
                if import_s >= MIN_TIMED_S:  # shorter: start-up's noise, not a rate
                    rates.append(input_mb / import_s)
            met = statistics.median(above) <= GOAL_MB
            failed |= not met
            print(
                f"{fmt:<14}{input_mb:9.1f}{_spread(floors):>22}{_spread(peaks):>22}"
                f"{_spread(above):>22}{_spread(rates) if rates else '-':>22}  "
                f"{'met' if met else 'NOT met'}",
                flush=True,
            )
    finally:
        if args.work is None:
            shutil.rmtree(work, ignore_errors=True)
    if args.short:
        print("short mode: a crash test; the figures of a few MB say nothing about the goal")
    elif failed:
        print(f"goal not met: a peak more than {GOAL_MB:.0f} MB above the floor")


if __name__ == "__main__":
    main()
