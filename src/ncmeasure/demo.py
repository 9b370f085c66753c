"""``ncmeasure demo``: the whole pipeline on a virtual machine, on any computer.

:func:`run_demo` writes the demo machine file, generates its NC programs,
runs them on the :class:`~ncmeasure.sim.machine.VirtualMachine`, serves the
drive signals through simulated drives (CiA 402 on a python-can virtual bus,
or a Modbus TCP server on 127.0.0.1), records them with the real link,
analyses the recording and writes the HTML report. The run itself is
:func:`~ncmeasure.virtual_run.run_programs`, the path ``ncmeasure dryrun``
takes with a user's own programs.

With an assembly variation the machine is measured twice, as the machine
maker would see it: first assembled correctly (the *reference*, the
fingerprint of the machine type), then with the variation; the comparison
names the likely cause of the change. A global change such as a preload
shows only against such a reference. An earlier demo folder without a
variation can serve as the reference (``reference=``), which saves its run.

The folder it writes::

    machine.toml        the demo machine (edit it, generate, simulate)
    programs/           the NC programs and schedule.json
    recording/          the recording of the measured machine
    results.json        its friction results
    truth.json          the virtual machine's own friction at every scheduled point
    report.html         the report (plots in report_plots/)
    reference/          with a variation: the correctly assembled machine's
                        recording/, results.json and truth.json
    comparison.json     with a variation: the change against the reference
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ncmeasure.acquire import AcquisitionResult
from ncmeasure.analysis.analyze import analyze
from ncmeasure.analysis.judgement.compare import compare_results
from ncmeasure.config import MachineConfig, parse_machine
from ncmeasure.errors import ConfigError
from ncmeasure.examples import DEMO_LINKS, demo_machine
from ncmeasure.formats.comparison import Comparison, write_comparison
from ncmeasure.formats.results import Results, load_results
from ncmeasure.formats.schedule import SCHEDULE_FILE, Schedule
from ncmeasure.program import generate_programs, load_dialect
from ncmeasure.recording import read_recording
from ncmeasure.sim.axis import Variation
from ncmeasure.sim.machine import MachineRun, VirtualMachine
from ncmeasure.sim.realism import Realism
from ncmeasure.virtual_run import (
    Progress,
    SimulatedLink,
    prepare_folder,
    record_directly,
    run_programs,
    simulated_link,
)

__all__ = ["AxisAccuracy", "DemoBench", "DemoResult", "DemoRun", "accuracy", "run_demo"]

_MARKER_FILE = ".ncmeasure-demo"
_OWN = (
    "machine.toml",
    "programs",
    "recording",
    "results.json",
    "truth.json",
    "report.html",
    "report_plots",
    "reference",
    "comparison.json",
    _MARKER_FILE,
)


@dataclass(frozen=True)
class AxisAccuracy:
    """How well the analysis recovered the virtual machine's own friction on one axis.

    Per measured point (position, direction, velocity step), the friction the
    analysis found (the median, minus the offset on a vertical axis) against
    the model's friction torque at that position and velocity.
    """

    axis: str
    points: int
    measured_mean_nm: float
    simulated_mean_nm: float
    median_error_percent: float
    """Median of the signed relative errors: a bias."""
    max_error_percent: float
    """Largest |relative error| of a single point."""


def accuracy(results: Results, vm: VirtualMachine) -> dict[str, AxisAccuracy]:
    """Compare ``results`` with the friction of the machine ``vm`` that was measured."""
    found: dict[str, AxisAccuracy] = {}
    for name, axis in results.axes.items():
        if name not in vm.models or axis.quantity != "torque_nm":
            continue
        model = vm.models[name]
        offset = axis.offset.value if axis.offset is not None and axis.vertical else 0.0
        measured: list[float] = []
        simulated: list[float] = []
        for position in axis.positions:
            for direction in position.directions.values():
                for point in direction.points if direction is not None else ():
                    measured.append(abs(point.median - offset))
                    simulated.append(
                        abs(
                            float(
                                model.friction_torque_nm(
                                    position.position_mm, point.velocity_mm_min
                                )
                            )
                        )
                    )
        if not measured:
            continue
        m, t = np.array(measured), np.array(simulated)
        errors = (m - t) / t * 100.0
        found[name] = AxisAccuracy(
            axis=name,
            points=len(measured),
            measured_mean_nm=float(m.mean()),
            simulated_mean_nm=float(t.mean()),
            median_error_percent=float(np.median(errors)),
            max_error_percent=float(np.abs(errors).max()),
        )
    return found


@dataclass
class DemoRun:
    """One measurement of the virtual machine."""

    label: str
    variation: Variation
    directory: Path
    """Where its recording/, results.json and truth.json are."""
    results: Results
    acquisition: AcquisitionResult | None
    """How the recording went (None for a reused reference)."""
    machine_time_s: float
    wall_time_s: float
    accuracy: dict[str, AxisAccuracy] = field(default_factory=dict)
    """Per axis: measured against simulated friction (empty for a reused reference)."""

    @property
    def recording(self) -> Path:
        """The recording directory."""
        return self.directory / "recording"

    @property
    def results_file(self) -> Path:
        """The results.json."""
        return self.directory / "results.json"


@dataclass
class DemoResult:
    """What ``run_demo`` wrote."""

    directory: Path
    link: str
    machine_file: Path
    programs: Path
    runs: list[DemoRun] = field(default_factory=list)
    """The reference first (with a variation), the measured machine last."""
    report: Path | None = None
    comparison: Comparison | None = None

    @property
    def measured(self) -> DemoRun:
        """The run of the machine with the variation (or the only run)."""
        return self.runs[-1]

    @property
    def comparison_file(self) -> Path | None:
        """comparison.json, when there is a reference."""
        return self.directory / "comparison.json" if self.comparison is not None else None


def _realism_key(realistic: bool, seed: int) -> dict[str, Any] | None:
    """How the demo's virtual machine was built, as truth.json keeps it."""
    return {"machine_seed": seed} if realistic else None


def _truth(
    vm: VirtualMachine, schedule: Schedule, realism: dict[str, Any] | None
) -> dict[str, Any]:
    """The model's friction torque at every scheduled position and velocity."""
    axes: dict[str, Any] = {}
    for summary in schedule.axes:
        model = vm.models[summary.name]
        velocities = list(summary.velocities_mm_min)
        positions = list(summary.nominal_positions_mm)
        table = model.friction_map(positions, velocities)
        axes[summary.name] = {
            "variation": {k: v for k, v in vars(model.variation).items() if v},
            "positions_mm": positions,
            "velocities_mm_min": velocities,
            "friction_nm": [[float(abs(x)) for x in row] for row in table],
            "gravity_nm": model.axis.gravity_torque_nm,
        }
    return {"unit": "Nm", "realism": realism, "axes": axes}


def _measure(
    config: MachineConfig,
    programs: Path,
    schedule: Schedule,
    variation: Variation,
    out: Path,
    *,
    label: str,
    link: SimulatedLink,
    seed: int,
    progress: Progress,
    realistic: bool = False,
    machine_seed: int = 0,
) -> DemoRun:
    realism = _realism_key(realistic, machine_seed)

    def write_truth(vm: VirtualMachine, _run: MachineRun) -> None:
        (out / "truth.json").write_text(
            json.dumps(_truth(vm, schedule, realism), indent=2) + "\n", encoding="utf-8"
        )

    done = run_programs(
        config,
        programs,
        schedule,
        out,
        link=link,
        notes=f"ncmeasure demo: virtual machine, {label}, simulated time (lockstep)",
        label=label,
        variations={axis.name: variation for axis in config.axes},
        seed=seed,
        progress=progress,
        on_simulated=write_truth,
        realism=Realism() if realistic else None,
        machine_seed=machine_seed,
    )
    # nothing stops the demo but Ctrl-C, which ends it: a run that returns is whole
    assert done.results is not None and done.acquisition is not None
    return DemoRun(
        label=label,
        variation=variation,
        directory=out,
        results=done.results,
        acquisition=done.acquisition,
        machine_time_s=done.machine_time_s,
        wall_time_s=done.wall_time_s,
        accuracy=accuracy(done.results, done.vm),
    )


def _reuse_reference(
    folder: Path, schedule: Schedule, realism: dict[str, Any] | None = None
) -> DemoRun:
    """The nominal run of an earlier demo folder, checked against this program and machine."""
    results_file = folder / "results.json"
    if not (folder / _MARKER_FILE).is_file() or not results_file.is_file():
        raise ConfigError(f"{folder}: not the folder of an earlier ncmeasure demo")
    if (folder / "reference").exists():
        raise ConfigError(
            f"{folder}: that demo ran with a variation; a reference must be a demo without one"
        )
    truth_file = folder / "truth.json"
    try:
        truth = json.loads(truth_file.read_text(encoding="utf-8"))
        earlier = truth.get("realism")  # absent in a demo of an ideal machine
    except (OSError, ValueError, AttributeError) as exc:
        raise ConfigError(
            f"{truth_file}: cannot tell which machine that demo measured ({exc}); "
            "run the reference again"
        ) from None
    if earlier != realism:

        def said(key: dict[str, Any] | None) -> str:
            return (
                "an ideal machine"
                if key is None
                else (f"a realistic machine (fingerprint seed {key.get('machine_seed')})")
            )

        raise ConfigError(
            f"{folder}: that demo measured {said(earlier)}, this one {said(realism)}: "
            "a reference must be the same machine (run the reference again, or use the same "
            "--realistic and --seed)"
        )
    results = load_results(results_file)
    if results.recording.config_hash not in (None, schedule.config_hash):
        raise ConfigError(
            f"{folder}: measured with another program (config {results.recording.config_hash}, "
            f"now {schedule.config_hash}); run the reference again"
        )
    return DemoRun(
        label="reference",
        variation=Variation(),
        directory=folder,
        results=results,
        acquisition=None,
        machine_time_s=0.0,
        wall_time_s=0.0,
    )


def run_demo(
    directory: str | Path,
    *,
    link: str = "canopen",
    variation: Variation | None = None,
    controller: str = "linuxcnc",
    reference: str | Path | None = None,
    seed: int = 0,
    force: bool = False,
    report: bool = True,
    progress: Progress | None = None,
    realistic: bool = False,
) -> DemoResult:
    """Run the demo into ``directory`` (see the module docstring).

    Args:
        directory: New or empty folder (or an earlier demo's with ``force``).
        link: ``canopen`` or ``modbus``.
        variation: Assembly variation of every axis; None or all zero: none.
        controller: Dialect of the programs the virtual machine runs
            (``linuxcnc`` or ``sinumerik-840d``; any dialect the reader knows).
        reference: An earlier demo folder without variation to compare with,
            instead of measuring the reference again.
        seed: Seed of the simulated noise (the machine with a variation gets seed + 1,
            so it never shares the reference's noise).
        force: Replace an earlier demo in ``directory``.
        report: Write report.html.
        progress: ``progress(stage, fraction)`` for a progress display.
        realistic: A virtual machine as real ones are (:class:`~ncmeasure.sim.realism.Realism`):
            a healthy fingerprint along the travel (from ``seed``, the same for the
            reference and the machine with the variation), drift between runs and the
            drives' real noise.

    Raises:
        ConfigError: unknown link, unusable reference.
        OutputError: ``directory`` is not usable.
        LinkError: the recording failed.
        NcMeasureError: anything else of the pipeline (programs, analysis).
    """
    if link not in DEMO_LINKS:
        raise ConfigError(f"link {link!r}: the demo records through {' or '.join(DEMO_LINKS)}")
    variation = variation or Variation()
    report_progress: Progress = progress or (lambda _stage, _fraction: None)
    directory = Path(directory)
    reference_dir = Path(reference) if reference is not None else None
    if reference_dir is not None and reference_dir.resolve() == directory.resolve():
        raise ConfigError(f"{directory}: the reference must be another demo folder")
    load_dialect(controller)  # an unknown controller fails before anything is written
    prepare_folder(
        directory, marker=_MARKER_FILE, own=_OWN, what="demo", command="demo", replace=force
    )

    report_progress("writing the machine file and the programs", None)
    config, machine_file, programs, schedule = _write_machine_and_programs(
        directory, controller, link
    )

    drives = simulated_link(config, link)  # the demo machine file's own [link]
    result = DemoResult(directory, link, machine_file, programs)
    varied = variation != Variation()
    if varied:
        if reference_dir is not None:
            result.runs.append(
                _reuse_reference(reference_dir, schedule, _realism_key(realistic, seed))
            )
        else:
            result.runs.append(
                _measure(
                    config,
                    programs,
                    schedule,
                    Variation(),
                    directory / "reference",
                    label="reference (assembled correctly)",
                    link=drives,
                    seed=seed,
                    progress=report_progress,
                    realistic=realistic,
                    machine_seed=seed,
                )
            )
    result.runs.append(
        _measure(
            config,
            programs,
            schedule,
            variation,
            directory,
            label="machine with the variation" if varied else "machine",
            link=drives,
            seed=seed + 1 if varied else seed,  # its own noise, not the reference's
            progress=report_progress,
            realistic=realistic,
            machine_seed=seed,
        )
    )
    if varied:
        base, measured = result.runs[0], result.runs[-1]
        result.comparison = compare_results(
            base.results, [measured.results], labels=["reference", "measured"]
        )
        write_comparison(result.comparison, directory / "comparison.json")
    if report:
        report_progress("writing the report", None)
        result.report = _write_report(result)
    return result


def _write_machine_and_programs(
    directory: Path, controller: str, link: str
) -> tuple[MachineConfig, Path, Path, Schedule]:
    """The demo machine's file and its measurement programs, written into ``directory``.

    Returns:
        The machine, its file, the programs' folder and their schedule.
    """
    text = demo_machine(controller, link)
    config = parse_machine(tomllib.loads(text))
    machine_file = directory / "machine.toml"
    machine_file.write_text(text, encoding="utf-8")
    generated = generate_programs(config)
    programs = directory / "programs"
    generated.write(programs)
    schedule = generated.schedule
    assert (programs / SCHEDULE_FILE).is_file()
    return config, machine_file, programs, schedule


@dataclass
class DemoBench:
    """The demo machine and its LinuxCNC programs, measured again and again without a link.

    The fast path of detection and false-alarm studies (``tests/analysis/judgement/
    test_detection.py``, ``benchmarks/detection.py``): every :meth:`measure` runs the
    programs on a :class:`~ncmeasure.sim.machine.VirtualMachine`, writes its signals
    with :func:`~ncmeasure.virtual_run.record_directly` into a new folder and analyses
    them as ``ncmeasure analyze`` would (about a second per measurement).
    """

    config: MachineConfig
    programs: Path
    schedule: Schedule
    folder: Path
    runs: int = 0

    @classmethod
    def create(cls, folder: Path) -> DemoBench:
        """Write the demo machine's file and programs into ``folder``, as the demo does."""
        config, _, programs, schedule = _write_machine_and_programs(folder, "linuxcnc", "canopen")
        return cls(config, programs, schedule, folder)

    def measure(self, seed: int, variation: Variation | None = None, **options: Any) -> Results:
        """One measurement, every axis with ``variation``, its noise from ``seed``.

        ``options`` go to the :class:`~ncmeasure.sim.machine.VirtualMachine`.
        """
        vm = VirtualMachine.from_programs(
            self.config,
            self.programs,
            seed=seed,
            variations={a.name: variation or Variation() for a in self.config.axes},
            **options,
        )
        self.runs += 1
        out = self.folder / f"run-{self.runs:03d}"
        record_directly(self.config, vm.run(), self.schedule, out)
        return analyze(out, schedule=self.schedule, machine=self.config)


def _write_report(result: DemoResult) -> Path:
    """The report of the measured machine (with the comparison, if any) in the demo folder."""
    from ncmeasure.report import write_report

    return write_report(
        result.measured.results,
        result.directory / "report.html",
        recording=read_recording(result.measured.recording),
        comparison=result.comparison,
        title="ncmeasure demo: friction of the virtual machine",
    )
