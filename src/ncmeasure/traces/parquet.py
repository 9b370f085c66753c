"""Apache Parquet files through a column map: each ``column`` names a column of the file.

Data platforms and pandas users keep recordings as Parquet. The column map
that reads a CSV reads them too; ``column`` names the Parquet column (by
name, or by 1-based position in the file's schema). The file is read with
pyarrow (the extra ``ncmeasure[parquet]``), imported only when such a file
is read, batch by batch: memory stays within one batch whatever the size.
A time column may hold numbers (x ``time.scale`` into seconds) or
timestamps (seconds from the first, which is the measurement's start).
"""

from __future__ import annotations

import datetime as dt
import logging
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, Final

import numpy as np
from numpy.typing import NDArray

from ncmeasure.errors import RecordingError
from ncmeasure.formats.recording import RecordingMeta
from ncmeasure.recording import check_times
from ncmeasure.traces.job import ImportJob
from ncmeasure.traces.merge import CHUNK_ROWS

__all__ = ["import_parquet_meta", "is_parquet"]

log = logging.getLogger(__name__)

_MAGIC: Final = b"PAR1"

Append = Callable[[NDArray[np.float64], NDArray[np.float64]], None]


def is_parquet(path: Path) -> bool:
    """True for a Parquet file (``PAR1`` at its start and end), whatever its name."""
    try:
        with path.open("rb") as file:
            head = file.read(4)
            file.seek(-4, 2)
            tail = file.read(4)
    except OSError:
        return False
    return head == _MAGIC and tail == _MAGIC


def import_parquet_meta(
    job: ImportJob,
    refs: Mapping[str, str | int],
    scales: Mapping[str, tuple[float, float]],
    period_s: float | None,
    open_sink: Callable[[], Append],
) -> RecordingMeta:
    """Read the mapped columns batch by batch, convert them and write the recording.

    Args:
        job: The import.
        refs: Target (``time_s``, channel names in the recording's order) ->
            column name or 1-based position.
        scales: Target -> ``(scale, offset)``.
        period_s: The sample period when there is no time column.
        open_sink: Opens the recording; returns its ``append``.

    Raises:
        RecordingError: pyarrow is missing, the file cannot be read, a column
            is missing or holds no numbers, or times do not increase.
    """
    path = job.path
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError as exc:
        raise RecordingError(
            f"{path}: a Parquet file needs pyarrow: pip install 'ncmeasure[parquet]'"
        ) from exc
    try:
        file = pq.ParquetFile(path)
    except (pa.ArrowException, OSError) as exc:
        raise RecordingError(f"{path}: not a Parquet file that can be read ({exc})") from exc
    names: list[str] = list(file.schema_arrow.names)
    columns = {t: _column_name(path, r, names) for t, r in refs.items()}
    job.note(f"{path.name}: Parquet file, {file.metadata.num_rows} rows, {len(names)} column(s)")
    others = [n for n in names if n not in columns.values()]
    if others:
        job.note(
            f"{len(others)} column(s) not in the column map, not imported: "
            f"{', '.join(map(repr, others))}"
        )
    targets = [t for t in refs if t != "time_s"]
    wanted = list(dict.fromkeys(columns.values()))
    append: Append | None = None
    first: Any = None
    previous_s = -np.inf
    rows = 0
    for batch in file.iter_batches(batch_size=CHUNK_ROWS, columns=wanted):
        data = {name: batch.column(name) for name in wanted}
        count = batch.num_rows
        if not count:
            continue
        if append is None:
            append = open_sink()  # before the start is found: opening sets it
        if "time_s" in refs:
            time_column = data[columns["time_s"]]
            if pa.types.is_timestamp(time_column.type):
                stamps = time_column.cast(pa.timestamp("ns", tz=time_column.type.tz)).to_numpy(
                    zero_copy_only=False
                )
                nanoseconds = stamps.astype("datetime64[ns]").astype(np.int64)
                if first is None:
                    first = int(nanoseconds[0])
                    when = dt.datetime.fromtimestamp(first / 1e9, tz=dt.UTC)
                    job.found_start(
                        when if time_column.type.tz else when.replace(tzinfo=None),
                        f"the first timestamp of column {columns['time_s']!r}",
                    )
                time_s = (nanoseconds - first).astype(np.float64) / 1e9
            else:
                scale, offset = scales["time_s"]
                time_s = _numbers(path, columns["time_s"], time_column) * scale + offset
            check_times(time_s, previous_s, _row_where(path, rows))
            previous_s = float(time_s[-1])
        else:
            assert period_s is not None
            time_s = np.arange(rows, rows + count, dtype=np.float64) * period_s
        values = np.column_stack(
            [
                _numbers(path, columns[t], data[columns[t]]) * scales[t][0] + scales[t][1]
                for t in targets
            ]
        )
        append(time_s, values)
        rows += count
    if rows < 2 and period_s is None:
        raise RecordingError(f"{path}: {rows} row(s); the sample period needs at least two")
    return job.finish()


def _row_where(path: Path, before: int) -> Callable[[int], str]:
    """``file: row n`` of a batch's row (``before`` rows came in earlier batches)."""

    def where(index: int) -> str:
        return f"{path}: row {before + index + 1}"

    return where


def _column_name(path: Path, ref: str | int, names: Sequence[str]) -> str:
    if isinstance(ref, int):
        if ref > len(names):
            raise RecordingError(
                f"{path}: column {ref} is beyond the file's {len(names)} column(s): "
                f"{', '.join(map(repr, names))}"
            )
        return names[ref - 1]
    if ref not in names:
        raise RecordingError(
            f"{path}: no column {ref!r}", [f"the file has: {', '.join(map(repr, names))}"]
        )
    return ref


def _numbers(path: Path, name: str, column: Any) -> NDArray[np.float64]:
    import pyarrow as pa

    kind = column.type
    if not (pa.types.is_integer(kind) or pa.types.is_floating(kind) or pa.types.is_boolean(kind)):
        raise RecordingError(f"{path}: column {name!r} holds {kind}, not numbers")
    return np.asarray(column.cast(pa.float64()).to_numpy(zero_copy_only=False), dtype=np.float64)
