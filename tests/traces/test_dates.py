"""When an imported trace was measured: from its data, from --measured-at, else unknown.

Never the time of the import: a back-filled old trace must not look like the newest
measurement of its machine.
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ncmeasure.cli import app
from ncmeasure.errors import ConfigError, RecordingError
from ncmeasure.recording import RecordingHead
from ncmeasure.traces import import_columns, import_trace, load_column_map
from ncmeasure.traces.text import iso_datetime, preamble_date
from tests.traces.conftest import FIXTURES

runner = CliRunner()
UNKNOWN = (
    "the data hold no date: the measurement's time is unknown (give it with --measured-at; "
    "the fleet store needs it)"
)


def run(*args: str | Path) -> tuple[int, str, str]:
    result = runner.invoke(app, [str(a) for a in args])
    return result.exit_code, result.stdout, result.stderr


def write(path: Path, rows: list[str]) -> Path:
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")
    return path


MAP_PERIOD = """\
skip_lines = 2
period_s = 0.1
[channels]
X_current_a = { column = "I" }
X_velocity_mm_min = { column = "v" }
"""
ROWS = ["I;v", "1,5;100", "1,75;200", "2;300"]


def test_an_import_without_a_date_has_no_start(tmp_path: Path) -> None:
    """The CSV of `ncmeasure export` holds no date: the start is unknown, not now."""
    result = import_trace(FIXTURES / "recording_export.csv", tmp_path / "rec")
    assert result.meta.start_utc is None
    assert RecordingHead.open(tmp_path / "rec").meta.start_utc is None
    assert any("measurement's time is unknown" in line for line in result.report)
    when = dt.datetime(2020, 1, 1, tzinfo=dt.UTC)
    result = import_trace(FIXTURES / "recording_export.csv", tmp_path / "r2", measured_at=when)
    assert result.meta.start_utc == "2020-01-01T00:00:00.000+00:00"


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("sinumerik_comma.csv", None),  # no preamble
        ("tncscope.sco", "2024-05-06T00:00:00.000+00:00"),  # %DATE=06.05.2024
        ("twincat_shared.csv", "2022-05-02T13:56:24.376+00:00"),  # Starttime of export
        ("sinumerik_trace.xml", "2024-05-06T08:15:00.000+00:00"),  # startTime, +02:00
    ],
)
def test_formats_take_the_date_their_data_hold(
    tmp_path: Path, name: str, expected: str | None
) -> None:
    result = import_trace(FIXTURES / name, tmp_path / "rec")
    assert result.meta.start_utc == expected
    if expected is None:
        assert UNKNOWN in result.report


def test_sinumerik_csv_takes_an_iso_date_before_its_header(
    tmp_path: Path, fixture_text: Callable[[str], str]
) -> None:
    text = fixture_text("sinumerik_spaces.csv").replace(
        "Trace FRICTION_X_Y, exported for ncmeasure tests",
        "Trace FRICTION_X_Y\nDate: 2024-03-05 14:22:10",
    )
    path = tmp_path / "trace.csv"
    path.write_text(text, encoding="utf-8")
    result = import_trace(path, tmp_path / "rec")
    assert result.meta.start_utc == "2024-03-05T14:22:10.000+00:00"
    assert (
        "measured at 2024-03-05 14:22:10 UTC (from the lines before the header, line 2 "
        "'Date: 2024-03-05 14:22:10', no time zone: taken as UTC)" in result.report
    )


def test_tncscope_takes_date_and_time(tmp_path: Path, fixture_text: Callable[[str], str]) -> None:
    text = fixture_text("tncscope.sco").replace("%DATE=06.05.2024", "%DATE=06.05.2024\n%TIME=14:22")
    path = tmp_path / "t.sco"
    path.write_text(text, encoding="utf-8")
    assert import_trace(path, tmp_path / "rec").meta.start_utc == "2024-05-06T14:22:00.000+00:00"


def test_a_column_map_takes_the_date_of_the_skipped_preamble(tmp_path: Path) -> None:
    data = write(tmp_path / "log.csv", ["Logger export v2", "Date: 2024-03-05 14:22:10", *ROWS])
    mapping = load_column_map(write(tmp_path / "m.toml", [MAP_PERIOD]))
    result = import_columns(data, tmp_path / "rec", mapping)
    assert result.meta.start_utc == "2024-03-05T14:22:10.000+00:00"
    # several different dates are no date
    data = write(
        tmp_path / "two.csv", ["from 2024-03-05 14:22:10", "to 2024-03-05 15:00:00", *ROWS]
    )
    result = import_columns(data, tmp_path / "rec2", mapping)
    assert result.meta.start_utc is None
    assert (
        "the lines before the header hold 2 different date-times: none is taken as the "
        "measurement's start" in result.report
    )
    # a date written in a locale's way is not taken
    data = write(tmp_path / "de.csv", ["Export", "Datum: 05.03.2024 14:22", *ROWS])
    assert import_columns(data, tmp_path / "rec3", mapping).meta.start_utc is None


COLLECTOR = [
    "Timestamp,I,v",
    "2024-03-05 10:00:00.000,1.5,100",
    "2024-03-05 10:00:00.100,1.75,200",
    "2024-03-05 10:00:00.250,2.0,300",
]


@pytest.mark.parametrize("declared", ["", 'format = "iso"'])
def test_a_time_column_of_date_times(tmp_path: Path, declared: str) -> None:
    """A data collector's timestamps: the times come from them, the start is the first."""
    data = write(tmp_path / "c.csv", COLLECTOR)
    spec = ", ".join(filter(None, ['column = "Timestamp"', declared]))
    mapping = write(
        tmp_path / "m.toml",
        [f"time = {{ {spec} }}", "[channels]", 'X_current_a = { column = "I" }',
         'X_velocity_mm_min = { column = "v" }'],
    )  # fmt: skip
    result = import_columns(data, tmp_path / "rec", mapping)
    rec = result.recording
    np.testing.assert_allclose(rec.time_s, [0.0, 0.1, 0.25], atol=1e-9)
    assert rec.meta.start_utc == "2024-03-05T10:00:00.000+00:00"
    assert any("from the first row of time column 'Timestamp'" in line for line in result.report)
    if not declared:
        assert any("holds ISO 8601 date-times (detected)" in line for line in result.report)


def test_a_bad_date_time_in_a_date_time_column_names_its_line(tmp_path: Path) -> None:
    rows = [*COLLECTOR[:2], "05.03.2024 10:00:01,1.75,200"]
    data = write(tmp_path / "c.csv", rows)
    mapping = write(
        tmp_path / "m.toml",
        ['time = { column = "Timestamp" }', "[channels]", 'X_current_a = { column = "I" }'],
    )
    with pytest.raises(RecordingError, match=r"c\.csv:3: time column 'Timestamp'"):
        import_columns(data, tmp_path / "rec", mapping)
    scaled = write(
        tmp_path / "s.toml",
        ['time = { column = "T", format = "iso", scale = 0.001 }', "[channels]",
         'X_current_a = { column = "I" }'],
    )  # fmt: skip
    with pytest.raises(ConfigError) as caught:
        load_column_map(scaled)
    assert "date-times are not scaled" in "\n".join(caught.value.problems)


def test_import_command_takes_measured_at(tmp_path: Path) -> None:
    source = FIXTURES / "recording_export.csv"
    code, _, err = run("import", source, "-o", tmp_path / "a", "--measured-at", "2024-03-05 14:22")
    assert code == 0, err
    assert RecordingHead.open(tmp_path / "a").meta.start_utc == "2024-03-05T14:22:00.000+00:00"
    code, _, err = run("import", source, "-o", tmp_path / "b", "--measured-at", "yesterday")
    assert code == 2 and "--measured-at 'yesterday': not an ISO 8601 date-time" in err
    assert "Traceback" not in err and not (tmp_path / "b").exists()
    code, out, _ = run("import", "--help")
    assert "--measured-at" in out and "UTC" in out


def test_iso_date_times_in_text() -> None:
    assert iso_datetime("Date: 2024-03-05 14:22:10") == dt.datetime(2024, 3, 5, 14, 22, 10)
    assert iso_datetime("2024-03-05T14:22:10.5+01:00") == dt.datetime(
        2024, 3, 5, 14, 22, 10, 500000, tzinfo=dt.timezone(dt.timedelta(hours=1))
    )
    assert iso_datetime("2024-03-05") is None  # a date alone
    assert iso_datetime("05.03.2024 14:22:10") is None  # the locale decides its reading
    assert iso_datetime("v2024-03-05 14:22") is None
    assert preamble_date(["a", "b"]) == (None, "")
