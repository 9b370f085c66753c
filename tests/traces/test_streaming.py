"""A large trace XML is parsed as a stream: memory stays bounded, values stay exact.

This is a memory property (tracemalloc), not a timing: nothing here depends on speed.
"""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import numpy as np

from ncmeasure.traces import import_trace

RECORDS = 200_000
MIB = 1 << 20


def write_large_trace(path: Path, records: int) -> None:
    """Current every 1 ms, position every 2 ms (left out of every other record)."""
    with path.open("w", encoding="utf-8") as file:
        file.write(
            '<?xml version="1.0" encoding="UTF-8"?>\n<traceSession version="2.0">\n'
            '<traceCaptureSetup><sessionSettings sessionName="LARGE"/></traceCaptureSetup>\n'
            '<traceData dataFrames="1"><dataFrame>\n<frameHeader startTime="x" dropOuts="0"/>\n'
            '<dataSignal id="f1" name="/Nck/!SD/nckServoDataActCurr64 [u1, 1]" interval="0.001"/>\n'
            '<dataSignal id="f2" name="/Nck/!SD/nckServoDataActPos1stEnc64 [u1, 1]"'
            ' interval="0.002"/>\n'
        )
        lines = []
        for i in range(records):
            current = f'f1="{(i % 1000) / 8!r}"'
            position = f' f2="{i / 16!r}"' if i % 2 == 0 else ""
            lines.append(f'<rec time="{i / 1000!r}" {current}{position}/>\n')
            if len(lines) == 10_000:
                file.write("".join(lines))
                lines.clear()
        file.write("".join(lines))
        file.write("</dataFrame></traceData></traceSession>\n")


def test_large_trace_memory_stays_bounded_and_values_are_exact(tmp_path: Path) -> None:
    path = tmp_path / "large.xml"
    write_large_trace(path, RECORDS)
    size = path.stat().st_size
    assert size > 7 * MIB
    calls: list[tuple[int, int]] = []

    def progress(done: int, total: int) -> None:
        calls.append((done, tracemalloc.get_traced_memory()[0]))

    tracemalloc.start()
    try:
        result = import_trace(path, tmp_path / "rec", axis_names={"1": "X"}, progress=progress)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()

    # While the file is read, what is held does not grow with it: one chunk of rows.
    during = [memory for done, memory in calls if done < size]
    assert len(during) >= 7
    assert max(during) < 4 * MIB
    assert max(during[len(during) // 2 :]) < 2 * max(during[: len(during) // 2]) + MIB
    # The peak adds the finished recording read back (rows x 3 float64), nothing like a tree.
    read_back = RECORDS * 3 * 8
    assert peak < read_back + 6 * MIB

    rec = result.recording
    i = np.arange(RECORDS)
    np.testing.assert_array_equal(rec.time_s, i / 1000)
    np.testing.assert_array_equal(rec.column("X_current_a"), (i % 1000) / 8)
    np.testing.assert_array_equal(rec.column("X_position_mm"), (i - i % 2) / 16)  # carried forward
    assert rec.meta.nominal_period_s == 0.001
    assert rec.meta.samples == RECORDS
