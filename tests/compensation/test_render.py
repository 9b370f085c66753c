"""The compensation files: golden files, the controllers' limits, LinuxCNC's halrun.

Run ``pytest --update-golden`` after an intended change of a template and
review the diff of tests/golden/compensation/ like code.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import tempfile
import tomllib
from pathlib import Path
from typing import Any

import pytest

from ncmeasure.compensation import render_compensation
from ncmeasure.config import MachineConfig, parse_machine
from ncmeasure.errors import ConfigError
from tests.compensation.example import TORQUE_CONSTANT, Z_OFFSET_A, example_results, x_friction_nm
from tests.conftest import example_data

GOLDEN = Path(__file__).parent.parent / "golden" / "compensation"
RATED_CURRENT_A = 17.7  # the example machine's
Z_NODE = 3


def _machine() -> MachineConfig:
    data = example_data("linuxcnc")
    for node, axis in enumerate(data["axes"], start=1):
        axis["link"] = {"node_id": node, "increments_per_rev": 10000}
    return parse_machine(data)


CASES: dict[str, dict[str, Any]] = {
    "twincat_X.lis": {"controller": "twincat", "axes": ["X"]},
    "linuxcnc.hal": {"controller": "linuxcnc", "axes": ["X", "Z"]},
    "cia402.toml": {"controller": "cia402"},
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_outputs_match_golden_files(name: str, update_golden: bool) -> None:
    text = render_compensation(
        example_results(), machine=_machine(), source="run1.results.json", **CASES[name]
    )
    path = GOLDEN / name
    if update_golden:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8", newline="\n")
    assert path.is_file(), "run pytest --update-golden to create the golden files"
    assert text == path.read_text(encoding="utf-8"), f"{name} differs from the golden file"


def _settings(text: str, pattern: str) -> dict[str, float]:
    return {m[0]: float(m[1]) for m in re.findall(pattern, text, re.MULTILINE)}


def test_twincat_table_holds_the_measured_current_at_its_speeds() -> None:
    text = render_compensation(example_results(), "twincat", axes=["X"], units_per_a=1000.0)
    speeds = _settings(text, r"^frict_comp\.table\[(\d+)\]\.in\s+(-?\d+)$")
    currents = _settings(text, r"^frict_comp\.table\[(\d+)\]\.out\s+(-?\d+)$")
    assert re.search(r"^frict_comp\.table_entries\s+20$", text, re.MULTILINE)
    assert re.search(r"^frict_comp\.mode\s+3$", text, re.MULTILINE)
    assert len(speeds) == len(currents) == 20
    assert speeds["0"] == currents["0"] == 0
    ordered = [speeds[str(i)] for i in range(20)]
    assert ordered == sorted(ordered) and len(set(ordered)) == 20  # ascending, >= 0
    assert ordered[1] == round(50.0 * 1000 / 60) and ordered[-1] == 100_000  # µm/s
    for i in range(1, 20):
        speed_mm_min = speeds[str(i)] * 60 / 1000
        mean_a = (
            x_friction_nm("positive", speed_mm_min) + x_friction_nm("negative", speed_mm_min)
        ) / (2 * TORQUE_CONSTANT)
        assert currents[str(i)] == pytest.approx(1000 * mean_a, abs=1.5)  # mA, whole numbers


def test_twincat_points_and_units() -> None:
    text = render_compensation(example_results(), "twincat", axes=["X"], points=5, units_per_a=1)
    assert re.search(r"^frict_comp\.table_entries\s+5$", text, re.MULTILINE)
    assert "frict_comp.table[5]" not in text
    assert re.search(r"^frict_comp\.table\[4\]\.out\s+1$", text, re.MULTILINE)  # 1.21 A
    with pytest.raises(ConfigError, match=r"twincat: --points 2 is outside 3…1000"):
        render_compensation(example_results(), "twincat", axes=["X"], points=2)


def test_linuxcnc_curve_is_monotonic_signed_and_within_limits() -> None:
    text = render_compensation(example_results(), "linuxcnc", axes=["X"])
    x = _settings(text, r"^setp ncm-x-friction\.x-val-(\d\d) (-?[\d.]+)$")
    y = _settings(text, r"^setp ncm-x-friction\.y-val-(\d\d) (-?[\d.]+)$")
    assert "personality=15" in text and len(x) == len(y) == 15
    xs = [x[f"{i:02d}"] for i in range(15)]
    ys = [y[f"{i:02d}"] for i in range(15)]
    assert xs == sorted(xs) and xs[7] == 0 and ys[7] == 0
    assert all(v < 0 for v in ys[:7]) and all(v > 0 for v in ys[8:])  # friction opposes motion
    assert xs[-1] == pytest.approx(6000 / 60) and xs[0] == pytest.approx(-6000 / 60)
    assert ys[-1] == pytest.approx(x_friction_nm("positive", 6000) / TORQUE_CONSTANT, abs=1e-4)
    assert ys[0] == pytest.approx(-x_friction_nm("negative", 6000) / TORQUE_CONSTANT, abs=1e-4)
    with pytest.raises(ConfigError, match=r"linuxcnc: --points 17 is outside 5…16"):
        render_compensation(example_results(), "linuxcnc", axes=["X"], points=17)


def test_cia402_torque_offset_of_the_vertical_axis() -> None:
    text = render_compensation(example_results(), "cia402", machine=_machine())
    value = round(1000 * Z_OFFSET_A / RATED_CURRENT_A)  # 113 ‰
    assert re.search(rf"^value = {value}\b", text, re.MULTILINE)
    assert f"node_id = {Z_NODE}" in text and 'axis = "Z"' in text and 'axis = "X"' not in text
    assert "index = 0x60B2" in text and 'data_type = "INTEGER16"' in text
    assert f"COB-ID 0x603, data 2BB26000{value:02X}000000" in text
    (write,) = tomllib.loads(text)["sdo_write"]
    assert write == {
        "axis": "Z",
        "node_id": Z_NODE,
        "index": 0x60B2,
        "subindex": 0,
        "data_type": "INTEGER16",
        "value": value,
    }


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"axes": ["X"]}, "axis X is not vertical in the results"),
        ({"machine": None}, "axis Z: the SDO write needs the drive's node id"),
        ({"points": 5}, "--points does not apply to cia402"),
    ],
)
def test_cia402_bad_input(kwargs: dict[str, Any], message: str) -> None:
    arguments: dict[str, Any] = {"machine": _machine(), **kwargs}
    with pytest.raises(ConfigError, match=re.escape(message)) as info:
        render_compensation(example_results(), "cia402", **arguments)
    assert "\n" not in str(info.value)


def test_cia402_needs_the_rated_current() -> None:
    data = example_data("linuxcnc")
    for node, axis in enumerate(data["axes"], start=1):
        axis["link"] = {"node_id": node}
        axis.pop("rated_current_a", None)
    with pytest.raises(ConfigError, match="gives no rated_current_a"):
        render_compensation(example_results(), "cia402", machine=parse_machine(data))


def test_unknown_controller() -> None:
    with pytest.raises(ConfigError, match="unknown controller 'fanuc'"):
        render_compensation(example_results(), "fanuc")


# --- LinuxCNC: the snippet loaded by halrun ----------------------------------------------

HALRUN = shutil.which("halrun")
#: The pins and parameters the manual pages give the three components (lincurve(9),
#: ddt(9), sum2(9)); the snippet may use no others.
DOCUMENTED = {
    "ddt": {"in", "out"},
    "lincurve": {"in", "out", "out-io"}
    | {f"x-val-{i:02d}" for i in range(16)}
    | {f"y-val-{i:02d}" for i in range(16)},
    "sum2": {"in0", "in1", "out", "gain0", "gain1", "offset"},
}
KINDS = {"vel": "ddt", "friction": "lincurve", "current": "sum2"}


def test_linuxcnc_snippet_uses_only_documented_pins() -> None:
    text = render_compensation(example_results(), "linuxcnc", axes=["X", "Z"])
    lines = [line for line in text.splitlines() if line and not line.startswith("#")]
    assert {line.split()[0] for line in lines} == {"loadrt", "addf", "setp", "net"}
    for name in re.findall(r"\bncm-[xz]-(\w+)\.([\w-]+)", text):
        kind, pin = name
        assert pin in DOCUMENTED[KINDS[kind]], f"{kind}.{pin} is not in the manual page"
    assert max(int(n) for n in re.findall(r"personality=(\d+),(\d+)", text)[0]) <= 16


_WAIT_FOR_THE_THREAD = """\
# until the servo thread has given the current (not 0), at most 60 s
for _ in $(seq 1200); do
    value=$(halcmd getp ncm-x-current.out)
    awk -v v="$value" 'BEGIN { exit !(v + 0 != 0) }' && exit 0
    sleep 0.05
done
exit 1
"""


def _halrun(script: str, workdir: Path) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ)
    if os.geteuid() == 0:
        # rtapi_app refuses to run as root without a fallback user; its FIFO then lives
        # in a folder that user may write.
        env["RTAPI_UID"] = "65534"
        env["RTAPI_FIFO_PATH"] = str(workdir / ".rtapi_fifo")
        workdir.chmod(0o777)
    (workdir / "wait.sh").write_text(_WAIT_FOR_THE_THREAD, encoding="utf-8")
    path = workdir / "test.hal"
    path.write_text(script, encoding="utf-8")
    return subprocess.run(
        [str(HALRUN), "-f", str(path)],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
        cwd=workdir,
        check=False,
    )


@pytest.mark.skipif(HALRUN is None, reason="LinuxCNC's halrun is not installed")
def test_linuxcnc_snippet_loads_in_halrun_and_interpolates() -> None:
    """halrun loads the snippet after a servo thread, and lincurve gives the friction
    current at a velocity between two breakpoints (the input pin set directly)."""
    snippet = render_compensation(example_results(), "linuxcnc", axes=["X", "Z"])
    x = _settings(snippet, r"^setp ncm-x-friction\.x-val-(\d\d) (-?[\d.]+)$")
    y = _settings(snippet, r"^setp ncm-x-friction\.y-val-(\d\d) (-?[\d.]+)$")
    velocity = (x["10"] + x["11"]) / 2
    expected = (y["10"] + y["11"]) / 2
    assert expected != 0  # wait.sh waits for a current other than 0
    script = (
        "loadrt threads name1=servo-thread period1=1000000\n"
        + snippet
        + "unlinkp ncm-x-friction.in\n"
        + f"setp ncm-x-friction.in {velocity}\n"
        + "start\n"
        + "loadusr -w sh wait.sh\n"  # until the thread has run: no time on a busy PC
        + "stop\n"
        + "getp ncm-x-friction.out\n"
        + "getp ncm-x-current.out\n"
    )
    with tempfile.TemporaryDirectory(prefix="ncm-hal-") as folder:
        done = _halrun(script, Path(folder))
    output = done.stdout + done.stderr
    if done.returncode != 0 and re.search(
        r"Refusing to run as root|rtapi_app exited without becoming ready|"
        r"already running|Permission denied",
        output,
    ):
        pytest.skip(f"halrun cannot start RTAPI here: {output.strip().splitlines()[-1]}")
    assert done.returncode == 0, output
    values = [float(v) for v in re.findall(r"^(-?\d+(?:\.\d+)?(?:e[-+]?\d+)?)$", done.stdout, re.M)]
    # lincurve's output, and sum2's: in0 (no PID here) 0 + gain1 1.0 x the friction
    assert values == pytest.approx([expected, expected], abs=1e-6), output
