"""The verdict with a reference: the change is judged, not the machine's fingerprint."""

from __future__ import annotations

import pytest

from ncmeasure.analysis.judgement.verdict import (
    ChangeFigures,
    comparison_verdict,
    names_change_cause,
)
from ncmeasure.formats.results import Verdict

RAIL = Verdict(
    level="check",
    reason="A moderate pattern: friction changes by 7.0 % along the travel (irregular): "
    "likely a misaligned guide rail.",
    action="Measure again to confirm; if it repeats, check the guide rails.",
)
NUT = Verdict(
    level="fault",
    reason="Friction changes by 21 % along the travel (high at both ends): likely a shifted "
    "or tilted ball-screw nut.",
    action="Check the alignment of the ball-screw nut to the bearings.",
)
HEALTHY = Verdict(level="ok", reason="No assembly fault shows.", action="None.")
FLAT = ChangeFigures("flat", "none", 0.6, 0.4)
LOOSE = ChangeFigures("rising_to_loose_bearing", "loose_bearing", 2.8, 1.2)
CHANGE = "friction +1.2 % on average, rising towards the loose bearing"


def test_an_unchanged_check_pattern_is_the_fingerprint() -> None:
    got = comparison_verdict(RAIL, "ok", CHANGE, signature="irregular", diagnosis=FLAT)
    assert got.level == "ok"
    assert "this machine's own fingerprint, not a change" in got.reason
    assert "misaligned guide rail" in got.reason  # said as what it is on its own
    assert got.action == "None. Keep comparing with the same reference."


def test_an_unchanged_fault_pattern_is_a_check_to_confirm() -> None:
    got = comparison_verdict(NUT, "ok", CHANGE, signature="high_at_both_ends", diagnosis=FLAT)
    assert got.level == "check"
    assert "not a change, but as strong as a fault on its own" in got.reason
    assert got.action.startswith("Compare the pattern with the reference's report")


def test_a_local_change_alone_is_a_check_that_names_its_cause_and_no_limit() -> None:
    got = comparison_verdict(
        HEALTHY, "warning", CHANGE, signature="flat", diagnosis=LOOSE, limit_status="ok"
    )
    assert got.level == "check"
    assert "within the limits; a change of 2.8 % along the travel: likely a shifted or " in (
        got.reason
    )
    assert "beyond the warning limit" not in got.reason
    assert got.reason.count("rising towards the loose bearing") == 1
    assert "loose bearing" in got.action and got.action.startswith("Measure again")


def test_the_change_leads_over_the_own_pattern() -> None:
    """The axis had its own nut-like pattern; now the loose bearing changed: the verdict
    names the change's cause first, the own finding after it."""
    got = comparison_verdict(
        RAIL, "warning", CHANGE, signature="irregular", diagnosis=LOOSE, limit_status="ok"
    )
    assert got.level == "check"
    assert got.reason.startswith("Against the reference:")
    assert "likely a shifted or tilted loose bearing" in got.reason
    assert got.reason.index("loose bearing") < got.reason.index("On its own:")
    assert "loose bearing" in got.action


def test_a_change_beyond_the_critical_limit_names_a_preload_loss() -> None:
    loss = ChangeFigures("flat", "preload_or_carriage", 0.4, -30.0)
    got = comparison_verdict(
        HEALTHY, "critical", "friction -30 % on average", diagnosis=loss, limit_status="critical"
    )
    assert got.level == "fault"
    assert got.reason.endswith(
        "beyond the critical limit; likely a preload loss of the ball-screw nut or the "
        "bearings, a guide carriage or the lubricant."
    )
    assert "preload" in got.action


@pytest.mark.parametrize(
    ("limits", "diagnosis", "named"),
    [
        ("ok", LOOSE, True),
        ("ok", FLAT, False),
        ("ok", ChangeFigures("flat", "preload_or_carriage", 0.5, 7.0), False),
        ("warning", ChangeFigures("flat", "preload_or_carriage", 0.5, 12.0), True),
        # a level change led by preload is no local change, whatever its shape
        ("ok", ChangeFigures("high_at_both_ends", "preload_or_carriage", 4.0, 8.0), False),
    ],
)
def test_when_the_cause_is_named(limits: str, diagnosis: ChangeFigures, named: bool) -> None:
    assert names_change_cause(limits, diagnosis) is named


def test_an_ok_verdict_never_names_a_cause() -> None:
    """Inconsistent inputs (a local diagnosis with status ok) still give no cause in an ok."""
    got = comparison_verdict(HEALTHY, "ok", CHANGE, diagnosis=LOOSE, limit_status="ok")
    assert got.level == "ok" and "likely" not in got.reason
