"""Property over the whole machine-file space, every dialect, random controller options.

Machine files are drawn the way users' typos and extremes produce them: wide
numeric ranges, infinities, NaN, the smallest float, strings for numbers,
unknown keys in any spelling, axis and program names a control reads as
something else, random controller options. ``ncmeasure generate`` must either

* exit 2 with a located message and leave the output folder as it was, or
* write programs that ``check`` accepts, that use only the dialect's own M
  codes and variables, and (linuxcnc, fanuc) that LinuxCNC's rs274 reads
  inside the soft limits and feeds.
"""

from __future__ import annotations

import math
import os
import re
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from ncmeasure.cli import app
from ncmeasure.formats.schedule import load_schedule
from ncmeasure.program import check_programs, load_dialect
from tests.conftest import DIALECTS, machine_toml
from tests.program.rs274 import AXES, RS274, check_against_schedule, fanuc_as_one_file, run_rs274

runner = CliRunner()

NASTY: list[Any] = [
    math.inf,
    -math.inf,
    math.nan,
    0,
    -1,
    5e-324,
    1e300,
    -1e300,
    1e-4,
    "40",
    "no",
    True,
    [],
    {},
    2**63,
]
AXIS_NAMES = ["X", "Y", "Z", "A", "B", "C", "U", "V", "W", "Q", "I", "J", "K", "E", "M", "XX"]
AXIS_NAMES += ["X1", "Z2", "XA1", "S", "F"]
PROGRAMS = ["FRICTION", "friction", "M3", "MM_3", "G0", "FR_1", "O1000", "P"]
UNKNOWN_KEYS = ["Park_mm", "park-mm", "PARK_MM", "margin_mn", "Positions"]


def log_floats(low: float, high: float) -> st.SearchStrategy[float]:
    """Floats spread over decades, as limits of real and mistyped machines are."""
    return st.floats(math.log10(low), math.log10(high)).map(lambda e: float(f"{10**e:.6g}"))


_WILD = {"on": False}


def mostly(typical: st.SearchStrategy[Any], extreme: st.SearchStrategy[Any]) -> Any:
    """What real machines have; in a wild draw, one value in four from the extremes."""
    return st.integers(0, 3).flatmap(lambda i: extreme if i == 0 and _WILD["on"] else typical)


@st.composite
def axis_table(draw: st.DrawFn, name: str) -> dict[str, Any]:
    low = draw(mostly(st.sampled_from([0.0, -500.0, -1200.0]), st.floats(-2e5, 2e5)))
    length = draw(mostly(st.floats(50, 3000), log_floats(0.01, 1e5)))
    table: dict[str, Any] = {
        "name": name,
        "travel_mm": [low, low + length],
        "park_mm": draw(
            mostly(st.floats(low, low + length), st.floats(low - 10, low + length + 10))
        ),
        "max_velocity_mm_min": draw(mostly(st.floats(1000, 60000), log_floats(1e-3, 2e6))),
        "max_acceleration_m_s2": draw(mostly(st.floats(0.5, 20), log_floats(1e-4, 500))),
        "max_jerk_m_s3": draw(mostly(st.floats(5, 500), log_floats(1e-4, 2e5))),
        "vertical": draw(st.booleans()),
    }
    if draw(st.booleans()):
        table["torque_constant_nm_per_a"] = draw(mostly(st.floats(0.1, 50), log_floats(1e-3, 1e4)))
        table["screw_lead_mm"] = draw(
            mostly(st.sampled_from([5.0, 10.0, 20.0]), log_floats(1e-2, 1e4))
        )
    if draw(st.booleans()):
        table["rapid_velocity_mm_min"] = draw(
            mostly(st.floats(10000, 60000), log_floats(1e-3, 2e6))
        )
    if draw(st.integers(0, 3)) == 0:
        table["rated_current_a"] = draw(mostly(st.floats(1, 100), log_floats(1e-3, 1e5)))
    if draw(st.integers(0, 3)) == 0:
        table["fixed_bearing_end"] = draw(mostly(st.sampled_from(["min", "max"]), st.just("mid")))
    if draw(st.integers(0, 5)) == 0:
        table["link"] = {"node_id": draw(mostly(st.integers(1, 127), st.integers(-1, 300)))}
    if draw(st.integers(0, 5)) == 0:
        table["measurement"] = {
            "velocity_steps": draw(mostly(st.integers(1, 30), st.integers(-1, 600)))
        }
    return table


@st.composite
def machine_files(draw: st.DrawFn) -> dict[str, Any]:
    dialect = draw(st.sampled_from(DIALECTS))
    _WILD["on"] = draw(st.booleans())  # half the files as a careful user writes them
    names = draw(
        mostly(
            st.lists(
                st.sampled_from(["X", "Y", "Z", "A", "B", "C"]), min_size=1, max_size=3, unique=True
            ),
            st.lists(st.sampled_from(AXIS_NAMES), min_size=1, max_size=3, unique=True),
        )
    )
    options = load_dialect(dialect).options
    keys = [*options, "marker", "Marker_R"] if _WILD["on"] else list(options)
    chosen = draw(st.lists(st.sampled_from(keys), max_size=3) if keys else st.just([]))
    controller_options = {
        key: draw(
            mostly(
                st.integers(0, 1000),
                st.one_of(st.integers(0, 99_999), st.booleans(), st.sampled_from(NASTY)),
            )
        )
        for key in chosen
    }
    measurement: dict[str, Any] = {
        "positions": draw(
            mostly(
                st.integers(1, 5),
                st.one_of(
                    st.integers(0, 6), st.lists(st.floats(-100, 1000), min_size=1, max_size=4)
                ),
            )
        ),
        "velocity_steps": draw(st.integers(1, 12)),
        "min_velocity_mm_min": draw(mostly(st.floats(1, 20), log_floats(1e-5, 1e4))),
        "max_velocity_fraction": draw(st.floats(0.05, 1.0)),
        "spacing": draw(st.sampled_from(["geometric", "linear"])),
        "window_s": draw(mostly(st.floats(0.02, 0.5), log_floats(1e-4, 5))),
        "settle_s": draw(st.floats(0, 0.5)),
        "margin_mm": draw(mostly(st.floats(0, 10), st.floats(0, 5000))),
        "warmup_strokes": draw(st.integers(0, 2)),
        "repetitions": draw(st.integers(1, 2)),
        "both_directions": draw(st.booleans()),
        "dwell_s": draw(
            mostly(st.sampled_from([0.0, 0.0, 0.001, 0.25]), st.sampled_from([0.0004, 0.0016]))
        ),
        "unfit_steps": draw(mostly(st.just("drop"), st.just("error"))),
    }
    optional = {  # set or left to their defaults, as users do
        "max_velocity_mm_min": mostly(st.floats(100, 20000), log_floats(1e-5, 1e7)),
        "warmup_velocity_mm_min": mostly(st.floats(100, 5000), log_floats(1e-5, 1e7)),
        "window_samples": mostly(st.integers(10, 200), st.integers(-1, 2_000_000)),
        "sample_period_ms": mostly(st.sampled_from([1.0, 2.0, 4.0]), log_floats(1e-3, 1e4)),
        "dynamics_safety": mostly(st.floats(1, 3), st.floats(0, 20)),
        "order": mostly(st.sampled_from(["velocity", "position"]), st.sampled_from(["pos", 1])),
    }
    for key, strategy in optional.items():
        if draw(st.integers(0, 3)) == 0:
            measurement[key] = draw(strategy)
    name = mostly(
        st.sampled_from(["HMX-400 #17", "Fräse 3 Müller", "机床 7"]),
        st.text(min_size=1, max_size=20),
    )
    data: dict[str, Any] = {
        "machine": {
            "name": draw(name),
            "controller": dialect,
            "program": draw(mostly(st.just("FRICTION"), st.sampled_from(PROGRAMS))),
            "program_number": draw(mostly(st.just(1000), st.sampled_from([1, 9990, 99_999_999]))),
            "controller_options": controller_options,
        },
        "axes": [draw(axis_table(name)) for name in names],
        "measurement": measurement,
    }
    if _WILD["on"] and draw(st.booleans()):
        data["limits"] = {"max_duration_h": draw(log_floats(0.01, 1000))}
        if draw(st.booleans()):
            data["limits"]["max_program_kb"] = draw(st.integers(0, 2_000_000))
        if draw(st.booleans()):
            data["limits"]["max_windows"] = draw(st.integers(0, 100_000))
    if draw(st.integers(0, 3)) == 0:  # an order of the axes, or one with a stranger
        for key in ("park_order", "measure_order"):
            if draw(st.booleans()):
                order = draw(st.permutations(names))
                data["machine"][key] = order + draw(
                    mostly(st.just([]), st.sampled_from([["Q"], [names[0]]]))
                )
    if draw(st.integers(0, 5)) == 0:
        data["link"] = {"type": draw(mostly(st.just("replay"), st.sampled_from(["can", 7])))}
    for _ in range(draw(st.integers(0, 2)) if _WILD["on"] else 0):  # a typo or an extreme
        where = draw(st.sampled_from(["machine", "measurement", "axis"]))
        table = data["axes"][0] if where == "axis" else data[where]
        key = draw(st.one_of(st.sampled_from(sorted(table)), st.sampled_from(UNKNOWN_KEYS)))
        table[key] = draw(st.sampled_from(NASTY))
    return data


def snapshot(folder: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }


# An error names its place: a key path, an axis, a file's line, or a template line. The
# header ("m.toml is not valid") does not count: the problem itself must be located.
_LOCATED = re.compile(
    r"(axes\[\d+\]|machine|measurement|limits|link)[.\[:]"
    r"|axis [A-Z][A-Z0-9]*:|\.toml:\d+|at line \d+|template \S+:\d+"
)
_M_WORD = re.compile(r"(?<![A-Z0-9_<%])M\s*(\d+)", re.I)


@settings(
    max_examples=int(os.environ.get("NCMEASURE_PROPERTY_EXAMPLES", "200")),
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(machine_files())
def test_generate_refuses_cleanly_or_writes_programs_check_accepts(data: dict[str, Any]) -> None:
    with tempfile.TemporaryDirectory() as folder:
        tmp = Path(folder)
        machine = tmp / "m.toml"
        machine.write_text(machine_toml(data), encoding="utf-8")
        out = tmp / "out"
        out.mkdir()
        (out / "notes.txt").write_text("the technician's notes")
        before = snapshot(out)
        result = runner.invoke(app, ["generate", str(machine), "-o", str(out), "-q"])
        output = result.stdout + result.stderr
        assert not isinstance(result.exception, Exception) or isinstance(
            result.exception, SystemExit
        ), f"{result.exception!r}\n{output}"
        assert "Traceback" not in output
        event(f"exit {result.exit_code}")
        if result.exit_code == 2:
            event(result.stderr.splitlines()[1].split(":")[0] if "\n  " in result.stderr else "-")
            assert result.stderr.startswith("error: "), output
            header, _, problems = result.stderr.partition("\n")
            assert _LOCATED.search(problems or header), output
            assert snapshot(out) == before, "a refused generate changed the folder"
            assert sorted(p.name for p in tmp.iterdir()) == ["m.toml", "out"]
            return
        assert result.exit_code == 0, output
        report = check_programs(out)
        assert report.ok and report.windows_found == report.windows_expected
        schedule = load_schedule(out / "schedule.json")
        assert sorted(p.name for p in out.iterdir()) == sorted(
            [*schedule.program_files, "schedule.json", "SETUP.md", "setup.html", "notes.txt"]
        )
        _only_the_dialects_m_codes(
            out, schedule.program_files, schedule.controller_options, schedule.controller
        )
        _only_the_marker_variables(
            out, schedule.program_files, schedule.controller_options, schedule.controller
        )
        axes = {a.name for a in schedule.axes}
        if schedule.controller in ("linuxcnc", "fanuc") and axes <= set(AXES) and RS274:
            main = schedule.main_program
            if schedule.controller == "fanuc":
                sync_m = int(schedule.controller_options.get("marker_sync_m", 0))
                main = fanuc_as_one_file(out, schedule.program_files, sync_m=sync_m)
            moves = run_rs274(out, main)
            check_against_schedule(moves, schedule, markers=schedule.marker_scope == "window")


def _code_lines(out: Path, files: list[str], comments: str) -> Iterator[tuple[str, str]]:
    """("file:line", the line without what ``comments`` matches) of every program line."""
    for name in files:
        text = (out / name).read_text(encoding="utf-8")
        for number, line in enumerate(text.splitlines(), start=1):
            yield f"{name}:{number}", re.sub(comments, " ", line)


def _only_the_dialects_m_codes(
    out: Path, files: list[str], options: dict[str, int | bool], controller: str
) -> None:
    """Every M number in the programs is the dialect's own or a marker option's value."""
    dialect = load_dialect(controller)
    allowed = set(dialect.codes.program_m) | {
        int(value)
        for key, value in options.items()
        if dialect.codes.options.get(key) is not None
        and dialect.codes.options[key].kind == "m"
        and value
    }
    for where, line in _code_lines(out, files, r"\(.*?\)|;.*$|^%\S*|<[^>]*>|^L\s+\S+"):
        for match in _M_WORD.finditer(line):
            assert int(match.group(1)) in allowed, f"{where}: {line.strip()}"


# How a program names a variable or an output, per dialect (written here, independently of
# the dialect data the checker reads).
_VARIABLES = {
    "fanuc": re.compile(r"#\s*(\d+)"),
    "sinumerik-840d": re.compile(r"\$R\[\s*(\d+)\s*\]|(?<![A-Z$_])R(\d+)\s*="),
    "linuxcnc": re.compile(r"M6[2-5]\s*P\s*(\d+)|M6[78]\s*E\s*(\d+)", re.I),
}


def _only_the_marker_variables(
    out: Path, files: list[str], options: dict[str, int | bool], controller: str
) -> None:
    """Every variable or output a program touches is a marker option's value."""
    pattern = _VARIABLES.get(controller)
    if pattern is None:  # TwinCAT and HEIDENHAIN mark with M functions only
        return
    codes = load_dialect(controller).codes.options
    allowed = {
        int(value)
        for key, value in options.items()
        if key in codes and codes[key].kind in ("variable", "output") and value is not True
    }
    if controller == "fanuc":  # the prolog's system variables: alarm, stop, positions read
        allowed |= {3000, 3006, *range(5021, 5030), *range(5041, 5050)}
    for where, line in _code_lines(out, files, r"\(.*?\)|;.*$"):
        for match in pattern.finditer(line):
            used = int(next(g for g in match.groups() if g is not None))
            assert used in allowed, f"{where}: {line.strip()} (allowed {allowed})"


@pytest.mark.parametrize("dialect", DIALECTS)
def test_the_property_draws_programs_that_are_written(dialect: str) -> None:
    """The strategy is no sieve: a plain draw of each dialect is generated, not refused."""
    from tests.conftest import example_data

    data = example_data(dialect)
    data["measurement"]["velocity_steps"] = 3
    with tempfile.TemporaryDirectory() as folder:
        machine = Path(folder) / "m.toml"
        machine.write_text(machine_toml(data), encoding="utf-8")
        result = runner.invoke(app, ["generate", str(machine), "-o", f"{folder}/out", "-q"])
        assert result.exit_code == 0, result.stderr
