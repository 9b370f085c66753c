"""The reader and checker catch what a broken template or a hand edit would do."""

from __future__ import annotations

import itertools
import json
import re
from collections.abc import Callable
from pathlib import Path

import pytest

from ncmeasure.config import MachineConfig, parse_machine
from ncmeasure.errors import ConfigError, DialectError, ProgramCheckError, ProgramError
from ncmeasure.formats import schedule as schedule_format
from ncmeasure.program import check_programs, generate_programs, load_dialect, reader
from ncmeasure.program.reader import read_programs
from ncmeasure.resources import builtin_dir
from tests.conftest import DIALECTS, FIXED_TIME, SPECIAL_REFUSALS, small_data

Make = Callable[..., MachineConfig]


def _generate(make_config: Make, dialect: str, folder: Path, **options: int) -> Path:
    config = make_config(dialect, small=True)
    if options:
        data = config.model_dump()
        data["machine"]["controller_options"] = options
        config = MachineConfig.model_validate(data)
    generate_programs(config, generated=FIXED_TIME).write(folder)
    return folder


def _edit(path: Path, pattern: str, replacement: str, count: int = 1) -> None:
    text = path.read_text(encoding="utf-8")
    new, n = re.subn(pattern, replacement, text, count=count, flags=re.M)
    assert n == count, f"pattern {pattern!r} not found in {path.name}"
    path.write_text(new, encoding="utf-8")


# (dialect, file of axis X, a window-end line of window 1, its replacement)
SUBFILES = {
    "linuxcnc": "friction_x.ngc",
    "sinumerik-840d": "FRICTION_X.SPF",
    "fanuc": "O1001.nc",
    "twincat": "FRICTION_X.nc",
    "heidenhain-iso": "FRICTION.I",
}


@pytest.mark.parametrize("dialect", DIALECTS)
def test_generated_programs_pass_the_check(dialect: str, make_config: Make, tmp_path: Path) -> None:
    report = check_programs(_generate(make_config, dialect, tmp_path))
    assert report.ok
    assert report.windows_found == report.windows_expected == 3 * 4 * 3 * 2


@pytest.mark.parametrize("dialect", DIALECTS)
def test_position_order_programs_pass_the_check(
    dialect: str, make_config: Make, tmp_path: Path
) -> None:
    """Every dialect writes the position-by-position order; the check holds it to limits
    and schedule like the default order."""
    config = make_config(dialect, small=True, order="position", repetitions=2)
    result = generate_programs(config, generated=FIXED_TIME)
    assert all(axis.order == "position" for axis in result.schedule.axes)
    result.write(tmp_path / "out")
    report = check_programs(tmp_path / "out")
    assert report.ok
    assert report.windows_found == report.windows_expected == 3 * 4 * 3 * 2 * 2


@pytest.mark.parametrize("dialect", DIALECTS)
def test_a_position_beyond_the_soft_limit_is_caught(
    dialect: str, make_config: Make, tmp_path: Path
) -> None:
    folder = _generate(make_config, dialect, tmp_path)
    # the first warm-up feed of X goes to 745 (usable end); push it past 750
    _edit(
        folder / SUBFILES[dialect],
        r"X\+?745\.000",
        "X+760.000" if dialect == "heidenhain-iso" else "X760.000",
    )
    with pytest.raises(ProgramCheckError, match=r"outside the soft limits \[0, 750\]"):
        check_programs(folder)


@pytest.mark.parametrize("dialect", DIALECTS)
def test_a_feed_above_the_maximum_is_caught(
    dialect: str, make_config: Make, tmp_path: Path
) -> None:
    folder = _generate(make_config, dialect, tmp_path)
    _edit(folder / SUBFILES[dialect], r"F15000\b", "F45000")
    with pytest.raises(ProgramCheckError, match="exceeds the maximum of axis X"):
        check_programs(folder)


@pytest.mark.parametrize("dialect", DIALECTS)
def test_a_window_that_moves_is_caught(dialect: str, make_config: Make, tmp_path: Path) -> None:
    folder = _generate(make_config, dialect, tmp_path)
    # window 1 of X starts at rest near 5 mm; its end is the second run block
    _edit(
        folder / SUBFILES[dialect],
        r"X\+?5\.848",
        "X+5.600" if dialect == "heidenhain-iso" else "X5.600",
    )
    with pytest.raises(ProgramCheckError, match=r"window 1 .* is not driven in order"):
        check_programs(folder)


@pytest.mark.parametrize(
    ("dialect", "pattern"),
    [
        ("linuxcnc", r"^M67 E0 Q2$"),
        ("sinumerik-840d", r"^WHEN TRUE DO \$R\[1\]=2$"),
        ("fanuc", r"^#500=2$"),
        ("twincat", r"^M80=2$"),
    ],
)
def test_a_missing_marker_is_caught(
    dialect: str, pattern: str, make_config: Make, tmp_path: Path
) -> None:
    folder = _generate(make_config, dialect, tmp_path)
    _edit(folder / SUBFILES[dialect], pattern, "")
    with pytest.raises(ProgramCheckError, match=r"marker is .* expected 2"):
        check_programs(folder)


def test_heidenhain_marker_m_functions_when_configured(make_config: Make, tmp_path: Path) -> None:
    folder = _generate(make_config, "heidenhain-iso", tmp_path, marker_m_on=50, marker_m_off=51)
    text = (folder / "FRICTION.I").read_text()
    assert re.search(r"^N\d+ G01 X\+5\.848 M91 M50 \*$", text, re.M)
    assert check_programs(folder).ok
    _edit(folder / "FRICTION.I", r" M50 \*$", " *")
    with pytest.raises(ProgramCheckError, match="marker is 0 during this feed, expected 1"):
        check_programs(folder)


def test_heidenhain_marker_needs_both_m_functions(make_config: Make, tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="marker_m_off is not set"):
        _generate(make_config, "heidenhain-iso", tmp_path, marker_m_on=50)


def test_parking_must_come_first(make_config: Make, tmp_path: Path) -> None:
    folder = _generate(make_config, "linuxcnc", tmp_path)
    _edit(folder / "friction.ngc", r"^G53 G0 Z-5\.000$", "")
    with pytest.raises(ProgramCheckError, match="parking every axis"):
        check_programs(folder)


def test_unknown_words_are_not_silently_read(make_config: Make, tmp_path: Path) -> None:
    folder = _generate(make_config, "sinumerik-840d", tmp_path)
    _edit(folder / "FRICTION_X.SPF", r"^G64$", "G64\nG91")
    with pytest.raises(ProgramError, match=r"FRICTION_X.SPF:\d+: incremental positioning"):
        check_programs(folder)
    folder = _generate(make_config, "twincat", tmp_path / "t")
    _edit(folder / "FRICTION_X.nc", r"^G17 G71 G90 G94$", "G17 G71 G90 G94 G41")
    with pytest.raises(ProgramError, match=r"G41 \(tool radius compensation left\) selects"):
        check_programs(folder)


def test_fanuc_integer_coordinates_are_micrometres(tmp_path: Path) -> None:
    dialect = load_dialect("fanuc")
    (tmp_path / "O0001.nc").write_text("%\nO0001\nG90 G00 X100\nG00 X100.\nM30\n%\n")
    trace = read_programs(dialect, tmp_path, "O0001.nc", {"X"})
    assert [m.target["X"] for m in trace.motions] == [pytest.approx(0.1), 100.0]
    assert trace.problems[0] == (
        "O0001.nc:3: X100 has no decimal point: FANUC 0i / 30i (custom macro B) reads it in "
        "its least input increment (0.001 mm, 0.001 s); write X100."
    )
    # a fragment without the prolog: the operator's offsets may still move it
    assert len(trace.problems) == 2 and "may still act on it" in trace.problems[1]


def test_missing_schedule_or_folder(tmp_path: Path) -> None:
    with pytest.raises(ProgramError, match="not a directory"):
        check_programs(tmp_path / "none")
    with pytest.raises(ProgramError, match="no schedule here"):
        check_programs(tmp_path)


def test_fanuc_calls_a_numbered_program_without_its_leading_zeros(tmp_path: Path) -> None:
    """O0002 is called as M98 P2: the same program on a FANUC control."""
    data = small_data("fanuc")
    data["machine"]["program_number"] = 1
    generate_programs(parse_machine(data), generated=FIXED_TIME).write(tmp_path)
    assert "M98 P2" in (tmp_path / "O0001.nc").read_text()
    assert check_programs(tmp_path).ok


# --- hand-edited folders: located problems, never a traceback ---------------------------------


def _schedule_edit(folder: Path, **changes: object) -> None:
    path = folder / "schedule.json"
    data = json.loads(path.read_text(encoding="utf-8"))
    data.update(changes)
    path.write_text(json.dumps(data), encoding="utf-8")


@pytest.mark.parametrize(
    ("main", "expected"),
    [
        ("schedule.json", "main_program: 'schedule.json' is not one of its program_files"),
        ("../friction.ngc", "main_program: '../friction.ngc' is not a plain file name"),
        ("/tmp/friction.ngc", "main_program: '/tmp/friction.ngc' is not a plain file name"),
        ("", "main_program: '' is not one of its program_files"),
    ],
)
def test_a_main_program_that_is_no_program_file_is_refused(
    main: str, expected: str, make_config: Make, tmp_path: Path
) -> None:
    folder = _generate(make_config, "linuxcnc", tmp_path)
    _schedule_edit(folder, main_program=main)
    with pytest.raises(ProgramError) as caught:
        check_programs(folder)
    assert not isinstance(caught.value, ProgramCheckError)
    assert expected in str(caught.value), str(caught.value)


def test_program_files_must_be_plain_names_with_the_dialects_extension(
    make_config: Make, tmp_path: Path
) -> None:
    folder = _generate(make_config, "linuxcnc", tmp_path)
    _schedule_edit(folder, program_files=["friction.ngc", "../x.ngc", "notes.txt"])
    with pytest.raises(ProgramError) as caught:
        check_programs(folder)
    text = str(caught.value)
    assert "program_files[1]: '../x.ngc' is not a plain file name" in text, text


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        ("[" * 100_000, "nested too deep (at line 1)"),
        ("1" * 5000, "integer of more than 4300 digits (at line 1)"),
        ('{"format": "ncmeasure-schedule", "blocks": ' + "9" * 5000 + "}", "4300 digits"),
    ],
)
def test_a_schedule_python_cannot_parse_is_located(
    content: str, expected: str, make_config: Make, tmp_path: Path
) -> None:
    folder = _generate(make_config, "linuxcnc", tmp_path)
    (folder / "schedule.json").write_text(content, encoding="utf-8")
    with pytest.raises(ProgramError) as caught:
        check_programs(folder)
    assert str(caught.value).startswith(f"{folder / 'schedule.json'}: invalid JSON")
    assert expected in str(caught.value)


@pytest.mark.parametrize(
    ("dialect", "line", "expected"),
    [
        ("linuxcnc", "M" + "9" * 5000, "M999999999999… (5000 digits) is not allowed"),
        ("fanuc", "M" + "0" * 4990 + "3", "M3 (spindle on, clockwise) is reserved"),
        ("fanuc", "O" + "1" * 5000, "program number 111111111111… (5000 digits) is beyond"),
        ("fanuc", "G" + "1" * 5000 + " X5.", "unexpected word G111111111111… (5000 digits)"),
        ("linuxcnc", "M" + "9" * 5000 + " G" + "1" * 5000, "(5000 digits)"),
        ("twincat", "R5=1", "unexpected word R5=1"),  # as written, not "R51"
    ],
)
def test_words_with_thousands_of_digits_are_located_problems(
    dialect: str, line: str, expected: str, make_config: Make, tmp_path: Path
) -> None:
    folder = _generate(make_config, dialect, tmp_path)
    sub = folder / SUBFILES[dialect]
    lines = sub.read_text(encoding="utf-8").splitlines()
    lines.insert(3, line)
    sub.write_text("\n".join(lines) + "\n", encoding="utf-8")
    with pytest.raises(ProgramError) as caught:
        check_programs(folder)
    assert f"{sub.name}:4: " in str(caught.value) and expected in str(caught.value), str(
        caught.value
    )


@pytest.mark.parametrize("kind", sorted(SPECIAL_REFUSALS))
def test_a_schedule_that_is_no_regular_file_is_not_read(
    kind: str,
    make_config: Make,
    tmp_path: Path,
    special_file: Callable[[str, Path], Path],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(schedule_format, "MAX_SCHEDULE_BYTES", 16 * 1024 * 1024)
    folder = _generate(make_config, "linuxcnc", tmp_path)
    path = special_file(kind, folder / "schedule.json")
    with pytest.raises(ProgramError) as caught:
        check_programs(folder)
    assert str(caught.value).startswith(f"{path}: ") and SPECIAL_REFUSALS[kind] in str(caught.value)


@pytest.mark.parametrize(
    ("kind", "expected"),
    [
        ("fifo", "friction_x.ngc: not a regular file"),
        ("device", "friction_x.ngc: not a regular file"),
        ("huge", "friction_x.ngc: 20 MiB"),
    ],
)
def test_a_program_file_that_is_no_regular_file_is_not_read(
    kind: str,
    expected: str,
    make_config: Make,
    tmp_path: Path,
    special_file: Callable[[str, Path], Path],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(reader, "MAX_PROGRAM_FILE_BYTES", 16 * 1024 * 1024)

    folder = _generate(make_config, "linuxcnc", tmp_path)
    special_file(kind, folder / "friction_x.ngc")
    with pytest.raises(ProgramError) as caught:
        check_programs(folder)
    assert expected in str(caught.value), str(caught.value)


# --- every line of every program file is read or refused ---------------------------------------


def _insert(path: Path, after_line: int, *lines: str) -> None:
    text = path.read_text(encoding="utf-8").split("\n")
    text[after_line:after_line] = list(lines)
    path.write_text("\n".join(text), encoding="utf-8")


@pytest.mark.parametrize("file", ["O1000.nc", "O1001.nc"])
def test_fanuc_blocks_between_the_tape_start_and_the_program_number_are_refused(
    file: str, make_config: Make, tmp_path: Path
) -> None:
    folder = _generate(make_config, "fanuc", tmp_path)
    _insert(folder / file, 1, "M3 S1000", "G0 X-99999.0", "#3001=1")
    with pytest.raises(ProgramCheckError) as caught:
        check_programs(folder)
    text = str(caught.value)
    assert f"{file}:2: M3 (spindle on, clockwise) is reserved" in text, text
    assert f"{file}:4: common macro variable 3001 is not one" in text, text
    assert f"{file}:3: 'G0 X-99999.0' stands before the first program number" in text, text


def test_a_template_writing_before_the_program_number_writes_nothing(
    make_config: Make, tmp_path: Path
) -> None:
    own = tmp_path / "templates" / "fanuc"
    own.mkdir(parents=True)
    main = (builtin_dir("templates") / "fanuc" / "main.j2").read_text(encoding="utf-8")
    (own / "main.j2").write_text(main.replace("%\n", "%\nG00 X5.000\n", 1), encoding="utf-8")
    result = generate_programs(
        make_config("fanuc", small=True), templates_dirs=[tmp_path / "templates"]
    )
    with pytest.raises(DialectError) as caught:
        result.write(tmp_path / "out")
    assert "O1000.nc:2: 'G00 X5.000' stands before the first program number" in str(caught.value)
    assert not (tmp_path / "out").exists()


def test_a_second_program_with_the_main_programs_number_is_refused(
    make_config: Make, tmp_path: Path
) -> None:
    folder = _generate(make_config, "fanuc", tmp_path)
    main = folder / "O1000.nc"
    original = main.read_text(encoding="utf-8")
    _edit(main, r"^G17 G21 G90 G94$", "G17 G21 G90 G94\nM3 S20000\nG0 X-90000.0")
    decoy = "\n".join(original.split("\n")[1:])  # the untouched main program without '%'
    sub = folder / "O1001.nc"
    sub.write_text(sub.read_text(encoding="utf-8").removesuffix("%\n") + decoy)
    with pytest.raises(ProgramCheckError) as caught:
        check_programs(folder)
    text = str(caught.value)
    assert "O1001.nc:" in text and "program 1000 again (first in O1000.nc:2)" in text, text
    assert "O1000.nc:7: M3 (spindle on, clockwise) is reserved" in text, text


def test_a_percent_line_in_the_middle_of_a_program_ends_it(
    make_config: Make, tmp_path: Path
) -> None:
    """LinuxCNC ends a file that starts with '%' at the next '%': the rest never runs."""
    folder = _generate(make_config, "linuxcnc", tmp_path)
    _edit(folder / "friction.ngc", r"^G64 P0.005$", "G64 P0.005\n%")
    with pytest.raises(ProgramCheckError) as caught:
        check_programs(folder)
    text = str(caught.value)
    assert "friction.ngc:9-" in text and "text after the closing '%' of line 8" in text, text
    assert "never reaches its end" in text, text


def test_a_percent_line_in_a_file_that_does_not_start_with_one_is_refused(
    make_config: Make, tmp_path: Path
) -> None:
    folder = _generate(make_config, "linuxcnc", tmp_path)
    _insert(folder / "friction_x.ngc", 5, "%")
    with pytest.raises(ProgramCheckError, match=r"friction_x.ngc:6: '%' where the file"):
        check_programs(folder)


@pytest.mark.parametrize(
    ("dialect", "line", "expected"),
    [
        ("linuxcnc", "\u2028", r"'\u2028' (U+2028) outside a comment"),
        ("linuxcnc", "G1 X5.000\u00a0", r"'\xa0' (U+00A0) outside a comment"),
        ("linuxcnc", "G4\tP1", r"'\t' (U+0009) outside a comment"),
        ("linuxcnc", "G4 P1\x0c", r"'\x0c' (U+000C)"),
        ("sinumerik-840d", "G4 F1 ; \u2028", r"'\u2028' (U+2028) is not printable"),
        ("fanuc", "(FRÄSE)", r"'Ä' (U+00C4) is not ASCII"),
        ("twincat", "\x1e", r"'\x1e' (U+001E)"),
    ],
)
def test_characters_a_control_cannot_read_are_refused(
    dialect: str, line: str, expected: str, make_config: Make, tmp_path: Path
) -> None:
    folder = _generate(make_config, dialect, tmp_path)
    _insert(folder / SUBFILES[dialect], 4, line)
    with pytest.raises(ProgramCheckError) as caught:
        check_programs(folder)
    assert f"{SUBFILES[dialect]}:5: character {expected}" in str(caught.value), str(caught.value)


def test_printable_text_in_comments_and_crlf_line_ends_are_read(tmp_path: Path) -> None:
    data = small_data("linuxcnc")
    data["machine"]["name"] = "Fräse 机床 #17"
    folder = tmp_path / "out"
    generate_programs(parse_machine(data), generated=FIXED_TIME).write(folder)
    assert "Fräse 机床" in (folder / "friction.ngc").read_text(encoding="utf-8")
    sub = folder / "friction_x.ngc"
    sub.write_bytes(sub.read_bytes().replace(b"\n", b"\r\n"))
    assert check_programs(folder).ok


def test_a_template_writing_a_line_separator_writes_nothing(
    make_config: Make, tmp_path: Path
) -> None:
    own = tmp_path / "templates" / "linuxcnc"
    own.mkdir(parents=True)
    main = (builtin_dir("templates") / "linuxcnc" / "main.j2").read_text(encoding="utf-8")
    (own / "main.j2").write_text(main.replace("G64 P0.005\n", "G64 P0.005\n\u2028\n"))
    result = generate_programs(
        make_config("linuxcnc", small=True), templates_dirs=[tmp_path / "templates"]
    )
    with pytest.raises(DialectError, match=r"friction.ngc:\d+: character '\\u2028'"):
        result.write(tmp_path / "out")


def test_a_feed_above_the_maximum_by_less_than_a_micrometre_per_minute_is_caught(
    make_config: Make, tmp_path: Path
) -> None:
    """The checker compares the feed as written, with no tolerance that could hide it."""
    data = small_data("linuxcnc")
    data["axes"][0]["max_velocity_mm_min"] = 15000.0009999999
    folder = tmp_path / "out"
    generate_programs(parse_machine(data), generated=FIXED_TIME).write(folder)
    assert check_programs(folder).ok
    _edit(folder / "friction_x.ngc", r"F15000$", "F15000.001")
    with pytest.raises(ProgramCheckError, match=r"feed 15000\.001 mm/min exceeds the maximum"):
        check_programs(folder)


def test_fanuc_dwells_and_coordinates_carry_a_decimal_point(tmp_path: Path) -> None:
    """Without one FANUC reads G04 X1 as 1 ms and X100 as 0.1 mm (least input increment)."""
    data = small_data("fanuc")
    data["measurement"]["dwell_s"] = 1
    data["axes"][1].setdefault("measurement", {})["dwell_s"] = 0.25
    folder = tmp_path / "out"
    generate_programs(parse_machine(data), generated=FIXED_TIME).write(folder)
    assert re.search(r"^G04 X1\.$", (folder / "O1001.nc").read_text(), re.M)
    assert re.search(r"^G04 X0\.25$", (folder / "O1002.nc").read_text(), re.M)
    assert check_programs(folder).ok
    _edit(folder / "O1001.nc", r"^G04 X1\.$", "G04 X1")
    _edit(folder / "O1002.nc", r"^G00 Y5\.000$", "G00 Y5")
    with pytest.raises(ProgramCheckError) as caught:
        check_programs(folder)
    text = str(caught.value)
    assert re.search(r"O1001.nc:\d+: X1 has no decimal point: FANUC .* reads it in", text), text
    assert re.search(r"O1002.nc:\d+: Y5 has no decimal point", text), text


def _runout_is_next_window(tiny: bool) -> dict[str, object]:
    """Machines whose run-out block of one run is exactly the next run's window block."""
    axis = {"name": "X", "max_velocity_mm_min": 30000, "max_acceleration_m_s2": 2.0}
    measurement: dict[str, object] = {"velocity_steps": 1, "settle_s": 0, "both_directions": False}
    if tiny:
        axis.update(travel_mm=[0.0, 0.01], park_mm=0.0, max_velocity_mm_min=1000)
        axis.update(max_jerk_m_s3=100000)
        measurement.update(positions=3, min_velocity_mm_min=10, max_velocity_mm_min=120)
        measurement.update(window_samples=1, sample_period_ms=0.01, dynamics_safety=1)
        measurement.update(margin_mm=0, warmup_strokes=0)
    else:
        axis.update(travel_mm=[0.0, 750.0], park_mm=375.0, max_jerk_m_s3=40.0)
        measurement.update(positions=[100.0, 110.0], max_velocity_mm_min=6000, window_s=0.1)
        measurement.update(dynamics_safety=1.9999999)
    return {
        "machine": {"name": "m", "controller": "linuxcnc"},
        "axes": [axis],
        "measurement": measurement,
    }


@pytest.mark.parametrize("dialect", DIALECTS)
@pytest.mark.parametrize("tiny", [False, True], ids=["realistic", "tiny"])
def test_windows_are_matched_by_their_runs_not_by_a_lookalike_block(
    dialect: str, tiny: bool, tmp_path: Path
) -> None:
    """A run's run-out may be the very block of the next window: plan and check agree."""
    data = _runout_is_next_window(tiny)
    data["machine"]["controller"] = dialect  # type: ignore[index]
    result = generate_programs(parse_machine(data), generated=FIXED_TIME)
    windows = result.schedule.axes[0].windows
    assert any(  # the lookalike is really there
        (a.window_end_mm, a.stop_mm) == (b.window_start_mm, b.window_end_mm)
        for a, b in itertools.pairwise(windows)
    )
    result.write(tmp_path / "out")
    report = check_programs(tmp_path / "out")
    assert report.windows_found == report.windows_expected == len(windows)


def test_a_run_far_beyond_the_planned_blocks_stops_with_a_problem(
    make_config: Make, tmp_path: Path
) -> None:
    """Read on, a hand-made 15 MB of moves would take the checker a gigabyte; it stops."""
    folder = _generate(make_config, "linuxcnc", tmp_path)
    sub = folder / "friction_x.ngc"
    lines = sub.read_text(encoding="utf-8").split("\n")
    at = next(n for n, line in enumerate(lines) if line.startswith("G53 G1 ")) + 1
    lines[at:at] = ["G53 G1 X5.000", "G53 G1 X6.000"] * 100_000
    sub.write_text("\n".join(lines), encoding="utf-8")
    with pytest.raises(ProgramCheckError) as caught:
        check_programs(folder)
    blocks = json.loads((folder / "schedule.json").read_text())["blocks"]
    assert f"more than the {blocks} moves, dwells and calls the schedule plans" in str(caught.value)
