"""Peak memory and time of ``ncmeasure analyze`` over the length of a recording.

Writes synthetic recordings of 1 h, 4 h and 24 h × 3 axes × 1 kHz (five
signals per axis, 16 float64 columns: about 460 MB per hour on disk) and
runs the real command on each, ``ncmeasure analyze RUN --schedule ... -o ...
-q`` (no ``--report``), in a fresh subprocess. It prints the child's peak
resident memory (``ru_maxrss`` of that process alone, from ``wait4``) and
its time per recorded hour, against two floors measured in the same run:

* memory: the interpreter with the same imports as the command and nothing
  read (what any analysis pays);
* time: reading ``samples.bin`` once, sequentially, in 8 MiB pieces (the I/O
  floor of any analysis that looks at every sample).

The goals (issue "performance"): at most 1 GiB at 24 h, and time linear in
length (seconds per recorded hour the same at every length).

A recording is one measurement program of about an hour
(:mod:`ncmeasure.sim.synthetic`, the program of ``benchmarks/analysis.py``)
written again and again, each copy later by the program's duration, frame
by frame with the real :class:`~ncmeasure.recording.RecordingWriter`: the
generator never holds more than the one-hour program. Recordings are cached
under ``--cache`` (default ``/tmp/ncmeasure-bench-memory``) and reused; 24 h
take about 11 GB of disk. Each run is limited to ``--limit-gib`` of address
space (default 6), so a length the analysis cannot hold fails in the child
("exceeded") instead of pressing on a shared computer.

Run: python benchmarks/analysis_memory.py [--hours 1 4 24] [--cache DIR] [--short]
(``--short``: a short program of about 7 minutes, one and two copies: checks
that everything runs, fails only on a crash, never on a figure.)
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

from measurement import measurement_axes

from ncmeasure.recording import SAMPLES_FILE, RecordingHead, RecordingWriter
from ncmeasure.samples import SampleBlock
from ncmeasure.sim.synthetic import simulate

RATE_HZ = 1000
ROWS_PER_FRAME = 250  # as the writer's flush thread writes them at 1 kHz
GOAL_BYTES = 1 << 30
IMPORTS = (
    "import numpy, scipy.ndimage, scipy.stats, pydantic; import ncmeasure.cli; "
    "from ncmeasure.analysis.analyze import analyze; "
    "from ncmeasure.formats.results import write_results; "
    "from ncmeasure.formats.schedule import load_schedule; "
    "from ncmeasure.recording import read_recording"
)


def _write(
    directory: Path, copies: int, steps: int, repetitions: int, with_marker: bool = True
) -> Path:
    """The recording of ``copies`` programs one after the other, and its schedule file.

    ``with_marker=False``: without the marker channels (the analysis finds the
    windows by the commanded velocity). ``benchmarks/analysis.py`` writes its 4 h
    recordings with it."""
    schedule_path = directory.with_name(directory.name + ".schedule.json")
    if directory.exists() and schedule_path.exists():
        try:
            if RecordingHead.open(directory).meta.status == "complete":
                return schedule_path
        except Exception:
            pass
    data = simulate(
        measurement_axes(steps, repetitions),
        sample_period_s=1.0 / RATE_HZ,
        with_marker=with_marker,
    )
    period = len(data.time_s) / RATE_HZ
    if directory.exists():
        for item in directory.iterdir():
            item.unlink()
    with RecordingWriter.create(
        directory,
        data.channels,
        nominal_period_s=1.0 / RATE_HZ,
        config_hash=data.schedule.config_hash,
        source="synthetic",
        notes=f"benchmarks/analysis_memory.py: {copies} copies of one program",
        faster_than_real_time=True,
    ) as writer:
        for copy in range(copies):
            for first in range(0, len(data.time_s), 50 * ROWS_PER_FRAME):
                last = first + 50 * ROWS_PER_FRAME
                writer.append(
                    SampleBlock(data.time_s[first:last] + copy * period, data.values[first:last])
                )
    schedule_path.write_text(data.schedule.model_dump_json(), encoding="utf-8")
    return schedule_path


def _run(command: list[str], limit_bytes: int) -> tuple[float, int, int]:
    """Seconds, peak RSS in bytes and exit status of ``command`` in a fresh process."""

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (limit_bytes, limit_bytes))

    start = time.perf_counter()
    child = subprocess.Popen(
        command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, preexec_fn=limit
    )
    assert child.stderr is not None
    error = child.stderr.read()
    _, status, usage = os.wait4(child.pid, 0)
    seconds = time.perf_counter() - start
    child.returncode = os.waitstatus_to_exitcode(status)
    if child.returncode:
        tail = error.decode(errors="replace").strip().splitlines()[-1:] or [""]
        print(f"    exit {child.returncode}: {tail[0][:160]}")
    return seconds, usage.ru_maxrss * 1024, child.returncode


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=int, nargs="+", default=[1, 4, 24])
    parser.add_argument("--cache", type=Path, default=Path("/tmp/ncmeasure-bench-memory"))
    parser.add_argument("--limit-gib", type=float, default=6.0, help="address space per run")
    parser.add_argument("--short", action="store_true", help="about 7 and 14 minutes")
    args = parser.parse_args()
    steps, repetitions, copies_list = (
        (10, 1, [1, 2]) if args.short else (50, 2, sorted(set(args.hours)))
    )
    limit = int(args.limit_gib * (1 << 30))
    args.cache.mkdir(parents=True, exist_ok=True)
    python = sys.executable

    _, floor_rss, _ = _run([python, "-c", IMPORTS], limit)
    print(f"floor: interpreter with the command's imports: {floor_rss / 2**20:.0f} MiB")
    print(
        f"{'recording':>24} {'rows':>12} {'GB':>6} {'read s/h':>9} {'analyze s/h':>12} "
        f"{'peak RSS':>10} {'vs floor':>9}"
    )
    results = []
    for copies in copies_list:
        tag = f"short{copies}" if args.short else f"{copies}h"
        directory = args.cache / f"recording-{tag}"
        start = time.perf_counter()
        schedule = _write(directory, copies, steps, repetitions)
        written_s = time.perf_counter() - start
        samples = directory / SAMPLES_FILE
        size = samples.stat().st_size
        rows = RecordingHead.open(directory).meta.samples or 0
        hours = rows / RATE_HZ / 3600
        read_s, _, _ = _run(
            [python, "-c", f"f=open({str(samples)!r},'rb',buffering=0)\nwhile f.read(8<<20): pass"],
            limit,
        )
        output = args.cache / f"{tag}.results.json"
        analyze_s, peak, status = _run(
            [python, "-m", "ncmeasure", "analyze", str(directory), "--schedule", str(schedule),
             "-o", str(output), "-q"],
            limit,
        )  # fmt: skip
        shown = "exceeded" if status else f"{peak / 2**20:.0f} MiB"
        print(
            f"{f'{hours:.2f} h (written {written_s:.0f} s)':>24} {rows:12,} {size / 1e9:6.1f} "
            f"{read_s / hours:9.1f} {analyze_s / hours:12.1f} {shown:>10} "
            f"{peak / floor_rss:8.1f}x"
        )
        results.append((hours, analyze_s / hours, peak, status))
    done = [r for r in results if r[3] == 0]
    if done:
        longest = max(done)
        per_hour = [r[1] for r in done]
        print(
            f"goal: <= 1 GiB at 24 h: longest analysed {longest[0]:.2f} h used "
            f"{longest[2] / 2**20:.0f} MiB ({'met' if longest[2] <= GOAL_BYTES else 'NOT met'}"
            f"{'' if longest[0] >= 24 else ', not at 24 h'}); time linear: "
            f"{min(per_hour):.1f} .. {max(per_hour):.1f} s per recorded hour "
            f"(spread {max(per_hour) / min(per_hour):.2f}x)"
        )
    failed = [r for r in results if r[3] != 0]
    if failed:
        print(
            f"not analysed within {args.limit_gib:g} GiB: "
            + ", ".join(f"{r[0]:.1f} h" for r in failed)
        )
    if args.short and failed:
        sys.exit(1)


if __name__ == "__main__":
    main()
