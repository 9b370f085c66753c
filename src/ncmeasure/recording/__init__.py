"""Recordings on disk: the format, a crash-safe writer, a fast reader, and the import sink.

A recording is a directory of ``meta.json``, ``samples.bin`` and
``events.jsonl`` (:mod:`.format`, described byte by byte in
``docs/recording-format.md``). :class:`RecordingWriter` (:mod:`.writer`)
appends sample blocks crash-safe; :class:`Recording` (:mod:`.reader`) reads
one back frame by frame; :class:`ImportSink` (:mod:`.sink`) is where every
importer writes. Recordings sit below the links: they speak the vocabulary of
:mod:`ncmeasure.samples` and import nothing of the links. CSV and MDF4
exchange live with the other importers, in :mod:`ncmeasure.traces.csv` and
:mod:`ncmeasure.traces.mdf4`.
"""

from __future__ import annotations

from ncmeasure.recording.format import (
    EVENTS_FILE,
    FRAME_HEADER,
    FRAME_MAGIC,
    MAX_FLUSH_INTERVAL_S,
    META_FILE,
    SAMPLES_FILE,
    axis_metadata,
    channel_from_name,
    machine_axis,
)
from ncmeasure.recording.reader import (
    Recording,
    RecordingHead,
    RowChunk,
    iter_chunks,
    read_recording,
)
from ncmeasure.recording.sink import ImportSink, check_times
from ncmeasure.recording.writer import RecordingWriter

__all__ = [
    "EVENTS_FILE",
    "FRAME_HEADER",
    "FRAME_MAGIC",
    "MAX_FLUSH_INTERVAL_S",
    "META_FILE",
    "SAMPLES_FILE",
    "ImportSink",
    "Recording",
    "RecordingHead",
    "RecordingWriter",
    "RowChunk",
    "axis_metadata",
    "channel_from_name",
    "check_times",
    "iter_chunks",
    "machine_axis",
    "read_recording",
]
