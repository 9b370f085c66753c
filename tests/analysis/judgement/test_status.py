"""The one rule of a machine's status: defaults with a physical meaning, absolute sanity."""

from __future__ import annotations

import numpy as np
import pytest

from ncmeasure.analysis.judgement.status import AxisFigures, FleetPlace, machine_status
from ncmeasure.formats.comparison import Limits
from ncmeasure.sim.axis import AxisModel, Variation


def _coulomb_nm(variation: Variation | None = None) -> float:
    """The virtual axis' Coulomb friction: the intercept of its friction over speed."""
    model = AxisModel(variation=variation)
    positions = np.linspace(50.0, 700.0, 5)
    speeds = np.array([1000.0, 2000.0, 4000.0, 8000.0])
    torque = [model.friction_torque_nm(positions, np.full(5, s)).mean() for s in speeds]
    return float(np.polyfit(speeds, torque, 1)[1])


def _axis(name: str, coulomb: float, verdict: str = "ok", spread: float = 3.0) -> AxisFigures:
    values = {"coulomb": coulomb, "viscous_per_m_min": 0.1, "spread_percent": spread}
    return AxisFigures(name, "Nm", verdict, values)


def _status(latest: float, base: float) -> str:
    return machine_status({"X": _axis("X", latest)}, baseline={"X": _axis("X", base)}).status


def test_a_nut_one_preload_class_too_high_is_at_least_a_warning() -> None:
    healthy = _coulomb_nm()
    preloaded = _coulomb_nm(Variation(nut_preload_change=1.5))
    assert preloaded / healthy - 1 == pytest.approx(0.19, abs=0.01)
    assert _status(preloaded, healthy) in ("warning", "critical")
    assert _status(healthy, preloaded) in ("warning", "critical")  # and back


@pytest.mark.parametrize("accuracy", [-0.015, 0.015])
def test_a_healthy_re_measurement_is_never_a_warning(accuracy: float) -> None:
    # both measurements off by the drive's torque accuracy, in opposite directions
    healthy = _coulomb_nm()
    assert _status(healthy * (1 + accuracy), healthy * (1 - accuracy)) == "ok"


def test_no_single_preload_change_of_the_model_is_critical() -> None:
    healthy = _coulomb_nm()
    for variation in (
        Variation(nut_preload_change=1.5),
        Variation(nut_preload_change=-0.99),
        Variation(nut_preload_change=-0.6, bearing_preload_change=-0.6),
    ):
        assert _status(_coulomb_nm(variation), healthy) == "warning", variation
    assert Limits().warning_percent == 10.0 and Limits().critical_percent == 25.0


def test_an_axis_with_many_times_its_siblings_friction_is_at_least_check() -> None:
    axes = {"X": _axis("X", 7.0), "Y": _axis("Y", 1.0), "Z": _axis("Z", 1.1)}
    judged = machine_status(axes)  # no baseline, no fleet: the first measurement
    assert judged.axes["X"].status == "warning"
    assert "6.7 × the median of the machine's other axes" in judged.axes["X"].reasons[0]
    assert judged.axes["Y"].status == judged.axes["Z"].status == "ok"
    # an axis of another quantity is no sibling
    amps = {"X": _axis("X", 7.0), "Y": AxisFigures("Y", "A", "ok", {"coulomb": 1.0})}
    assert machine_status(amps).status == "ok"


def test_an_axis_far_outside_its_fleet_is_at_least_check_with_few_machines() -> None:
    place = [FleetPlace("coulomb", median=1.0, modified_z=None, machines=2)]
    far = machine_status({"X": _axis("X", 3.5)}, fleet={"X": place})
    assert far.status == "warning"
    assert "3.5 × its type's fleet median" in far.reasons[0]
    near = machine_status({"X": _axis("X", 1.4)}, fleet={"X": place})
    assert near.status == "ok"


def test_the_verdict_enters_the_status() -> None:
    assert machine_status({"X": _axis("X", 1.0, "check")}).status == "warning"
    assert machine_status({"X": _axis("X", 1.0, "fault")}).status == "critical"


def test_viscous_friction_is_shown_not_judged() -> None:
    base = {"X": _axis("X", 1.0)}
    warm = {"X": AxisFigures("X", "Nm", "ok", {"coulomb": 1.0, "viscous_per_m_min": 0.07})}
    judged = machine_status(warm, baseline=base)
    assert judged.status == "ok"
    (change,) = [c for c in judged.axes["X"].changes if c.characteristic == "viscous_per_m_min"]
    assert change.change == pytest.approx(-30.0)


@pytest.mark.parametrize(
    ("latest", "base", "which"),
    [
        (None, 1.0, "the latest"),
        (1.0, None, "the baseline"),
        (None, None, "the latest and the baseline"),
    ],
)
def test_a_change_that_cannot_be_judged_is_never_a_silent_ok(
    latest: float | None, base: float | None, which: str
) -> None:
    def figures(coulomb: float | None) -> AxisFigures:
        values = {"coulomb": coulomb, "viscous_per_m_min": 0.1, "spread_percent": 3.0}
        return AxisFigures("X", "Nm", "ok", values)

    judged = machine_status({"X": figures(latest)}, baseline={"X": figures(base)})
    assert judged.status == "warning"
    assert judged.reasons == [
        f"axis X: no friction line in {which} measurement: the change since the baseline "
        "cannot be judged"
    ]
    # at least a warning: a fault stays critical
    faulty = AxisFigures("X", "Nm", "fault", figures(latest).values)
    assert machine_status({"X": faulty}, baseline={"X": figures(base)}).status == "critical"
    # without a baseline nothing changes: there is no change to judge
    assert machine_status({"X": figures(latest)}).status == "ok"
    # Coulomb friction on both sides: judged on it, as before
    assert machine_status({"X": figures(1.02)}, baseline={"X": figures(1.0)}).status == "ok"


def test_the_change_alone_is_kept_apart_from_the_verdict() -> None:
    """What a comparison adds to an axis' own verdict: the change since the baseline alone."""
    fault = machine_status({"X": _axis("X", 1.0, "fault")}, baseline={"X": _axis("X", 1.0)})
    assert (fault.status, fault.axes["X"].change_status) == ("critical", "ok")
    moved = machine_status({"X": _axis("X", 0.85)}, baseline={"X": _axis("X", 1.0)})
    assert (moved.status, moved.axes["X"].change_status) == ("warning", "warning")
    assert machine_status({"X": _axis("X", 1.0)}).axes["X"].change_status == "ok"
