"""Which machine a stored measurement belongs to, and when it was measured.

A machine file names a type, the serial comes with the measurement; a measurement's time
is when it was measured, never when it was imported or analysed.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ncmeasure.cli import app
from ncmeasure.errors import ConfigError
from ncmeasure.formats.results import Results, write_results
from ncmeasure.store import measurement_info, open_store

Make = Callable[..., Results]
runner = CliRunner()


def run(*args: str | Path) -> tuple[int, str, str]:
    result = runner.invoke(app, [str(a) for a in args])
    return result.exit_code, result.stdout, result.stderr


def _error(code: int, err: str) -> str:
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    return lines[0]


def _undated(make_results: Make, factor: float = 1.0) -> Results:
    """The results of an imported trace whose data held no date, analysed in 2032."""
    results = make_results("2032-06-01T09:00:00+00:00", factor)
    recording = results.recording.model_copy(
        update={"start_utc": None, "directory": "recordings/backfilled"}
    )
    return results.model_copy(update={"recording": recording})


def test_a_backfilled_trace_without_date_does_not_become_the_latest(
    tmp_path: Path, make_results: Make
) -> None:
    """An old trace imported (and analysed) after the machine wore does not hide the
    fault: without its date it is refused, with its date it is older than the latest."""
    store = f"sqlite:///{tmp_path / 'fleet.db'}"
    for name, when, factor in (
        ("delivery", "2026-01-10T08:00:00+00:00", 1.0),
        ("worn", "2031-01-10T08:00:00+00:00", 0.5),
    ):
        path = write_results(make_results(when, factor), tmp_path / f"{name}.json")
        assert run("store", "add", path, "--serial", "M17", "--store", store)[0] == 0
    assert run("store", "check", "M17", "--store", store)[0] == 3
    old = write_results(_undated(make_results), tmp_path / "backfilled.json")

    code, _, err = run("store", "add", old, "--serial", "M17", "--store", store)
    line = _error(code, err)
    assert "the measurement's time is unknown (the import found no date)" in line
    assert "--measured-at" in line

    code, _, err = run("store", "add", old, "--serial", "M17", "--measured-at", "2020-01-01",
                       "--store", store)  # fmt: skip
    assert code == 0, err
    code, out, _ = run("store", "check", "M17", "--store", store, "-o", tmp_path / "check.json")
    assert code == 3 and "status: critical" in out
    check = json.loads((tmp_path / "check.json").read_text())
    assert check["latest"]["measured_utc"].startswith("2031-01-10")
    code, out, _ = run("store", "show", "M17", "--store", store)
    assert "2020-01-01 00:00:00" in out


def test_measured_at_is_an_iso_date(tmp_path: Path, make_results: Make) -> None:
    path = write_results(_undated(make_results), tmp_path / "r.json")
    code, _, err = run("store", "add", path, "--serial", "M17", "--measured-at", "5.3.2024",
                       "--store", f"sqlite:///{tmp_path / 'fleet.db'}")  # fmt: skip
    assert "--measured-at '5.3.2024': not an ISO 8601 date-time" in _error(code, err)


def test_the_store_never_takes_the_analysis_time_for_the_measured_time(
    tmp_path: Path, make_results: Make
) -> None:
    with open_store(f"sqlite:///{tmp_path / 'fleet.db'}", write=True) as store:
        with pytest.raises(ConfigError, match="time is unknown"):
            store.add(_undated(make_results), measurement_info(serial="M17"))
        added = store.add(
            _undated(make_results),
            measurement_info(serial="M17", measured_utc="2024-03-05 14:22:10"),
        )
        _, measurements = store.machine("M17")
    assert [m.id for m in measurements] == [added.measurement_id]
    assert measurements[0].measured_utc == "2024-03-05T14:22:10.000+00:00"


def test_results_of_another_serial_are_refused(tmp_path: Path, make_results: Make) -> None:
    results = make_results("2026-01-10T08:00:00+00:00")
    recording = results.recording.model_copy(update={"serial": "M18"})
    path = write_results(results.model_copy(update={"recording": recording}), tmp_path / "r.json")
    store = f"sqlite:///{tmp_path / 'fleet.db'}"
    code, _, err = run("store", "add", path, "--serial", "M17", "--store", store)
    line = _error(code, err)
    assert "'M18'" in line and "'M17'" in line
    code, out, err = run("store", "add", path, "--serial", "M18", "--store", store)
    assert code == 0 and "of M18" in out, err


def test_machines_without_a_type_are_not_made_fleet_peers(
    tmp_path: Path, make_results: Make
) -> None:
    """Results that name no machine (a trace analysed without a machine file) need the
    type: two unrelated machines never become peers of a type "(unnamed)"."""
    store = f"sqlite:///{tmp_path / 'fleet.db'}"
    paths = []
    for number, when in enumerate(("2026-01-10T08:00:00+00:00", "2026-02-10T08:00:00+00:00")):
        results = make_results(when)
        recording = results.recording.model_copy(update={"machine": None})
        paths.append(
            write_results(
                results.model_copy(update={"recording": recording}), tmp_path / f"{number}.json"
            )
        )
    code, _, err = run("store", "add", paths[0], "--serial", "A1", "--store", store)
    line = _error(code, err)
    assert "name the machine type: --type TYPE, or analyse with --machine FILE" in line
    assert run("store", "add", paths[0], "--serial", "A1", "--type", "Lathe 2",
               "--store", store)[0] == 0  # fmt: skip
    assert run("store", "add", paths[1], "--serial", "B7", "--store", store)[0] == 2
    code, out, _ = run("store", "list", "--store", store)
    assert code == 0 and "(unnamed)" not in out and "Lathe 2" in out
    # a machine already in the store keeps its type
    later = make_results("2027-01-10T08:00:00+00:00", 0.9)
    recording = later.recording.model_copy(update={"machine": None})
    path = write_results(later.model_copy(update={"recording": recording}), tmp_path / "l.json")
    assert run("store", "add", path, "--serial", "A1", "--store", store)[0] == 0
