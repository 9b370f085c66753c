"""Every file's header: declared once, stamped on a model built in code, checked on reading."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from ncmeasure._version import __version__
from ncmeasure.errors import ConfigError
from ncmeasure.formats.comparison import Comparison
from ncmeasure.formats.header import FileHeader, read_file
from ncmeasure.formats.recording import RecordingMeta
from ncmeasure.formats.results import Results
from ncmeasure.formats.schedule import Schedule

FILES: list[type[FileHeader]] = [Schedule, RecordingMeta, Results, Comparison]


@pytest.mark.parametrize("model", FILES, ids=lambda m: m.FORMAT)
def test_the_schema_names_the_format_and_its_version(model: type[FileHeader]) -> None:
    properties = model.model_json_schema()["properties"]
    assert properties["format"]["const"] == model.FORMAT
    assert properties["format_version"]["default"] == model.FORMAT_VERSION
    assert model.FORMAT.startswith("ncmeasure-") and model.FORMAT_VERSION >= 1


def test_a_model_built_in_code_carries_its_header() -> None:
    meta = RecordingMeta.model_validate(
        {
            "channels": [{"name": "X_current_a", "axis": "X", "signal": "current_a", "unit": "A"}],
            "nominal_period_s": 0.001,
            "start_utc": "2026-01-01T00:00:00+00:00",
        }
    )
    assert (meta.format, meta.format_version) == ("ncmeasure-recording", 1)
    assert meta.ncmeasure_version == __version__
    dumped = meta.model_dump(mode="json")
    assert list(dumped)[:3] == ["format", "format_version", "ncmeasure_version"]


def test_a_model_of_another_format_is_refused() -> None:
    with pytest.raises(ValidationError, match="format must be 'ncmeasure-results'"):
        Results.model_validate({"format": "ncmeasure-schedule"})


def test_read_file_refuses_a_newer_version_in_one_line(tmp_path: Path) -> None:
    path = tmp_path / "schedule.json"
    path.write_text('{"format": "ncmeasure-schedule", "format_version": 7}', encoding="utf-8")
    with pytest.raises(ConfigError) as caught:
        read_file(path, Schedule, ConfigError, what="schedule", max_bytes=1024)
    assert str(caught.value) == (
        f"{path}: schedule format_version 7 is newer than this ncmeasure reads (1); "
        "update ncmeasure"
    )
