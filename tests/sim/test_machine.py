"""The virtual machine executes the generated program: its motion is the program's."""

from __future__ import annotations

import itertools
import pickle
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

from ncmeasure.config import MachineConfig, parse_machine
from ncmeasure.errors import ConfigError, ProgramError
from ncmeasure.examples import demo_machine
from ncmeasure.formats.schedule import Schedule
from ncmeasure.program import generate_programs
from ncmeasure.sim.axis import Variation
from ncmeasure.sim.machine import MachineRun, VirtualMachine


def _programs(tmp: Path, controller: str) -> tuple[MachineConfig, Schedule, Path]:
    config = parse_machine(tomllib.loads(demo_machine(controller, "canopen")))
    generated = generate_programs(config)
    folder = tmp / controller
    generated.write(folder)
    return config, generated.schedule, folder


@pytest.fixture(scope="module")
def linuxcnc(tmp_path_factory: pytest.TempPathFactory) -> tuple[Schedule, Path, MachineRun]:
    config, schedule, folder = _programs(tmp_path_factory.mktemp("vm"), "linuxcnc")
    return schedule, folder, VirtualMachine.from_programs(config, folder).run()


def test_marked_spans_are_the_scheduled_windows(
    linuxcnc: tuple[Schedule, Path, MachineRun],
) -> None:
    schedule, _, run = linuxcnc
    planned = [w for axis in schedule.axes for w in axis.windows]
    spans = [s for s in run.spans if s.axis]
    assert len(spans) == len(planned) == 2 * 5 * 8 * 2  # axes, positions, steps, directions
    for span, window in zip(spans, planned, strict=True):
        assert span.axis == window.axis
        assert span.marker == window.id
        assert span.velocity_mm_min == pytest.approx(window.velocity_mm_min, rel=1e-9)
        length = abs(window.window_end_mm - window.window_start_mm)
        expected_s = length / abs(window.velocity_mm_min) * 60.0
        assert span.end_s - span.start_s == pytest.approx(expected_s, abs=1e-6)
        # at constant velocity: the commanded velocity holds over the whole span
        axis = run.axes.index(span.axis)
        inside = slice(int(np.ceil(span.start_s / run.dt_s)), int(np.floor(span.end_s / run.dt_s)))
        assert np.allclose(run.velocity_cmd_mm_min[axis, inside], span.velocity_mm_min)
        # and the axis is where the schedule puts the window (the actual position lags
        # the command by the servo's following error, v · 2ζ/ω)
        lag = abs(span.velocity_mm_min) / 60.0 * 2 * 0.7 / (2 * np.pi * 20.0)
        middle = run.position_mm[axis, round((span.start_s + span.end_s) / 2 / run.dt_s)]
        centre = (window.window_start_mm + window.window_end_mm) / 2
        assert abs(middle - centre) <= lag * 1.05 + 0.01


def test_program_duration_matches_the_planned_estimate(
    linuxcnc: tuple[Schedule, Path, MachineRun],
) -> None:
    schedule, _, run = linuxcnc
    program_s = run.program_end_s - run.program_start_s
    assert program_s == pytest.approx(schedule.duration_s, rel=0.05)
    # the axes stand still before and after the program
    before = round(run.program_start_s / run.dt_s) - 1
    assert np.all(run.velocity_cmd_mm_min[:, : before + 1] == 0.0)
    assert np.all(run.velocity_cmd_mm_min[:, round(run.program_end_s / run.dt_s) + 1 :] == 0.0)


def test_axes_stay_inside_their_limits(linuxcnc: tuple[Schedule, Path, MachineRun]) -> None:
    schedule, _, run = linuxcnc
    for i, summary in enumerate(schedule.axes):
        low, high = summary.travel_mm
        command = run.velocity_cmd_mm_min[i]
        assert np.abs(command).max() <= summary.max_velocity_mm_min * (1 + 1e-9)
        position = np.cumsum(command) * run.dt_s / 60.0  # integrated command, relative
        assert np.ptp(position) <= high - low


def test_sinumerik_programs_move_the_machine_exactly_like_linuxcnc_programs(
    tmp_path: Path, linuxcnc: tuple[Schedule, Path, MachineRun]
) -> None:
    config, _, folder = _programs(tmp_path, "sinumerik-840d")
    sinumerik = VirtualMachine.from_programs(config, folder).run()
    reference = linuxcnc[2]
    assert sinumerik.marker.shape == reference.marker.shape
    assert np.allclose(sinumerik.velocity_cmd_mm_min, reference.velocity_cmd_mm_min)
    assert np.allclose(sinumerik.position_mm, reference.position_mm, atol=1e-9)
    assert [(s.marker, s.axis) for s in sinumerik.spans] == [
        (s.marker, s.axis) for s in reference.spans
    ]


def test_a_wrong_program_gives_wrong_data(tmp_path: Path) -> None:
    config, schedule, folder = _programs(tmp_path, "linuxcnc")
    sub = folder / "friction_x.ngc"
    text = sub.read_text(encoding="utf-8")
    # the first window's run-up asks for the lowest velocity; ask for 30 % more
    slowest = schedule.axes[0].windows[0].velocity_mm_min
    feed = f"F{slowest:g}\n"
    assert feed in text
    sub.write_text(text.replace(feed, f"F{slowest * 1.3:g}\n", 1), encoding="utf-8")
    run = VirtualMachine.from_programs(config, folder).run()
    first = next(s for s in run.spans if s.axis == "X")
    assert first.velocity_mm_min == pytest.approx(slowest * 1.3)


def test_a_move_outside_the_travel_stops_the_virtual_machine(tmp_path: Path) -> None:
    config, _, folder = _programs(tmp_path, "linuxcnc")
    sub = folder / "friction_x.ngc"
    text = sub.read_text(encoding="utf-8")
    sub.write_text(text.replace("G0 X5.000", "G0 X-20.000", 1), encoding="utf-8")
    with pytest.raises(ProgramError, match=r"friction_x.*axis X would move to -20 mm"):
        VirtualMachine.from_programs(config, folder)


def test_a_dry_run_follows_the_program_beyond_the_limits(tmp_path: Path) -> None:
    """``beyond_limits="follow"``: the machine drives a block beyond the travel and a feed
    above the maximum as written and names each block; the extremes say how far it went.
    ``stop`` (the default) refuses the first and drives the second at the maximum."""
    config, _, folder = _programs(tmp_path, "linuxcnc")
    sub = folder / "friction_x.ngc"
    text = sub.read_text(encoding="utf-8")
    warmup = "G1 X745.000 F12000\n"  # the warm-up stroke, along the whole travel
    assert warmup in text and "G0 X5.000\n" in text
    text = text.replace(warmup, "G1 X745.000 F60000\n", 1)  # X's maximum: 50 000
    sub.write_text(text, encoding="utf-8")
    capped = VirtualMachine.from_programs(config, folder).run().extremes(commanded=True)["X"]
    assert capped.velocity_mm_min == pytest.approx(50000.0)
    sub.write_text(text.replace("G0 X5.000\n", "G0 X-20.000\n", 1), encoding="utf-8")
    vm = VirtualMachine.from_programs(config, folder, beyond_limits="follow")
    assert len(vm.excursions) == 2
    assert re.fullmatch(
        r"friction_x\.ngc:\d+: axis X to -20 mm, outside its travel \[0, 750\] mm",
        vm.excursions[0],
    )
    assert re.fullmatch(
        r"friction_x\.ngc:\d+: axis X at 60000 mm/min, above its maximum velocity 50000 mm/min",
        vm.excursions[1],
    )
    run = vm.run()
    commanded, actual = run.extremes(commanded=True)["X"], run.extremes()["X"]
    assert commanded.min_position_mm == pytest.approx(-20.0)
    assert commanded.velocity_mm_min == pytest.approx(60000.0)
    assert commanded.acceleration_m_s2 == pytest.approx(6.0)  # the axis' maximum, never more
    # the servo follows: overshooting a little after the ramps
    assert -20.1 < actual.min_position_mm < -20.0
    assert 60000.0 < actual.velocity_mm_min < 61000.0
    assert 6.0 < actual.acceleration_m_s2 < 6.5
    # the other axis never moved beyond its own limits
    z = run.extremes(commanded=True)["Z"]
    assert -500.0 <= z.min_position_mm <= z.max_position_mm <= 0.0


def test_a_variation_for_an_unknown_axis_is_refused(tmp_path: Path) -> None:
    config, _, folder = _programs(tmp_path, "linuxcnc")
    with pytest.raises(ConfigError) as info:
        VirtualMachine.from_programs(config, folder, variations={"Q": Variation(nut_shift_um=10)})
    assert "axis Q: the machine has no such axis" in str(info.value.problems)


def test_runs_are_reproducible_and_pickle(tmp_path: Path) -> None:
    config, _, folder = _programs(tmp_path, "linuxcnc")
    first = VirtualMachine.from_programs(config, folder, seed=3).run()
    again = VirtualMachine.from_programs(config, folder, seed=3).run()
    other = VirtualMachine.from_programs(config, folder, seed=4).run()
    assert np.array_equal(first.current_a, again.current_a)
    assert not np.array_equal(first.current_a, other.current_a)
    copy = pickle.loads(pickle.dumps(first))
    t = first.spans[5].start_s + 0.01
    assert copy.state(1, t) == first.state(1, t)
    # before the start and after the end: standing still where the machine is
    assert first.state(0, -5.0).velocity_cmd_mm_min == 0.0
    end = first.state(0, first.duration_s + 100.0)
    assert end.velocity_cmd_mm_min == 0.0


def test_the_current_carries_friction_gravity_and_inertia(
    linuxcnc: tuple[Schedule, Path, MachineRun], tmp_path: Path
) -> None:
    config, _, folder = _programs(tmp_path, "linuxcnc")
    vm = VirtualMachine.from_programs(config, folder)
    run = linuxcnc[2]
    for span in (s for s in run.spans if s.axis):
        axis = run.axes.index(span.axis)
        model = vm.models[span.axis]
        inside = slice(int(np.ceil(span.start_s / run.dt_s)), int(np.floor(span.end_s / run.dt_s)))
        current = float(np.median(run.current_a[axis, inside]))
        # friction, gravity, cogging at the actual positions, inertia 0 at constant velocity
        noiseless = model.motor_current_a(run.position_mm[axis, inside], span.velocity_mm_min)
        assert current == pytest.approx(float(np.median(noiseless)), abs=0.012), span
    # the vertical axis Z holds its load: about 7.4 A at standstill
    z = run.axes.index("Z")
    assert float(np.median(run.current_a[z, :100])) == pytest.approx(
        vm.models["Z"].axis.gravity_torque_nm / 2.1, abs=0.05
    )


def test_the_virtual_machine_moves_through_every_point_linuxcnc_commands(tmp_path: Path) -> None:
    """LinuxCNC's own interpreter (rs274) reads the same programs: the virtual machine's
    commanded path passes every end point rs274 emits, in order, at the feed it names,
    with the marker it sets."""
    from tests.program.test_rs274 import RS274, run_rs274

    if RS274 is None:
        pytest.skip("rs274 not installed (apt-get install linuxcnc-uspace); CI installs it")
    config, schedule, folder = _programs(tmp_path, "linuxcnc")
    moves = run_rs274(folder, schedule.main_program)
    run = VirtualMachine.from_programs(config, folder).run()
    x, z = run.axes.index("X"), run.axes.index("Z")
    command = run.position_cmd_mm[[x, z]]
    pointer, checked = 0, 0
    previous = np.array([[np.nan], [np.nan]])
    for move in moves:
        target = np.array([[move.position[0]], [move.position[2]]])
        # a block end inside a segment is passed at speed: within one grid step of travel
        tolerance = 1e-4 + (move.feed / 60.0 * run.dt_s if move.kind == "feed" else 0.0)
        hits = np.flatnonzero(np.all(np.abs(command[:, pointer:] - target) <= tolerance, axis=0))
        if move.kind == "rapid" and not hits.size and pointer == 0:
            continue  # a park move of an axis already there: no motion
        assert hits.size, f"the virtual machine never reaches {move}"
        end = pointer + int(hits[0])
        length = float(np.abs(target - previous).max())
        previous = target
        if move.kind == "feed" and length > 10 * tolerance:  # long enough to sample inside
            middle = (pointer + end) // 2
            speed = float(np.hypot(*run.velocity_cmd_mm_min[[x, z], middle]))
            assert speed <= move.feed * (1 + 1e-9)
            assert run.marker[middle] == move.marker, move
            checked += 1
        pointer = end
    assert checked >= 2 * 160  # at least every run-up and window of both axes


def test_a_program_for_an_axis_the_machine_lacks_is_refused(tmp_path: Path) -> None:
    config, _, folder = _programs(tmp_path, "linuxcnc")
    only_x = config.model_copy(update={"axes": [config.axes[0]]})
    with pytest.raises(ProgramError, match=r"friction\.ngc:\d+: moves axis Z, which the machine"):
        VirtualMachine.from_programs(only_x, folder)


def test_position_order_is_found_by_the_analysis(tmp_path: Path) -> None:
    """The demo machine measured position by position: the virtual machine runs the
    programs, its signals become a recording, and the analysis finds every window, one
    per position, direction and velocity step, and the model's friction in them."""
    from ncmeasure.analysis.analyze import analyze
    from ncmeasure.demo import accuracy
    from ncmeasure.recording import Recording, RecordingWriter

    data = tomllib.loads(demo_machine("linuxcnc", "canopen"))
    data["measurement"]["order"] = "position"
    config = parse_machine(data)
    generated = generate_programs(config)
    folder = tmp_path / "programs"
    generated.write(folder)
    schedule = generated.schedule
    vm = VirtualMachine.from_programs(config, folder)
    run = vm.run()
    # the machine drives the windows position by position
    for axis in schedule.axes:
        by_id = {w.id: w for w in axis.windows}
        spans = [by_id[round(s.marker)] for s in run.spans if s.axis == axis.name]
        assert len(spans) == len(axis.windows)
        visited = [p for p, _ in itertools.groupby(w.position_index for w in spans)]
        assert visited == list(range(5))
    channels, block = run.sample(0.004)
    with RecordingWriter.create(
        tmp_path / "recording", channels, nominal_period_s=0.004, machine=config
    ) as writer:
        writer.append(block)
    results = analyze(Recording.open(tmp_path / "recording"), schedule=schedule, machine=config)
    steps = 8
    for name, axis in results.axes.items():
        assert axis.window_source == "marker"
        assert axis.windows == 5 * steps * 2, name
        assert [p.position_index for p in axis.positions] == [0, 1, 2, 3, 4]
        for position in axis.positions:
            for direction in ("positive", "negative"):
                found = position.directions[direction]
                assert found is not None, (name, position.position_index, direction)
                assert sorted(p.step for p in found.points) == list(range(steps))
                assert all(p.windows == 1 for p in found.points)
    for name, found in accuracy(results, vm).items():
        assert found.points == 5 * steps * 2, name
        assert abs(found.median_error_percent) <= 1.5, found
        assert found.max_error_percent <= 10.0, found
