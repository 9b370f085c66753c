"""A compensation refuses an axis with an assembly fault, and says what it averaged."""

from __future__ import annotations

import pytest

from ncmeasure.compensation import render_compensation
from ncmeasure.errors import ConfigError
from ncmeasure.formats.results import Results, Verdict
from tests.compensation.example import example_results


def _with_fault(results: Results, axis: str) -> Results:
    verdict = Verdict(
        level="fault",
        reason="friction changes by 40 % along the travel, likely a shifted loose bearing",
        action="check the loose bearing",
    )
    axes = dict(results.axes)
    axes[axis] = axes[axis].model_copy(update={"verdict": verdict})
    return results.model_copy(update={"axes": axes})


def test_an_axis_whose_verdict_is_fault_is_refused_unless_forced() -> None:
    results = _with_fault(example_results(), "X")
    with pytest.raises(ConfigError, match=r"axis X: the verdict is fault .*--force"):
        render_compensation(results, "twincat", axes=["X"])
    forced = render_compensation(results, "twincat", axes=["X"], force=True)
    assert "frict_comp" in forced


def test_the_file_says_how_much_the_averaged_positions_differ() -> None:
    text = render_compensation(example_results(), "linuxcnc", axes=["X"])
    # the example's X has 20 % more friction at its second position (X_FACTORS)
    (line,) = [line for line in text.splitlines() if line.startswith("# axis X:")]
    assert "averaged over 2 position(s) (100, 600 mm)" in line
    assert "differ by up to 18.2 %" in line
