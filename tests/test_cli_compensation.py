"""`ncmeasure compensation`: the files it writes and its one-line refusals."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from ncmeasure.cli import app
from ncmeasure.formats.results import write_results
from tests.compensation.example import example_results

runner = CliRunner()
GOLDEN = Path(__file__).parent / "golden" / "compensation"


def run(*args: str | Path) -> tuple[int, str, str]:
    result = runner.invoke(app, [str(a) for a in args])
    return result.exit_code, result.stdout, result.stderr


@pytest.fixture
def results_file(tmp_path: Path) -> Path:
    return write_results(example_results(), tmp_path / "run1.results.json")


@pytest.fixture
def machine_file(tmp_path: Path) -> Path:
    code, text, _ = run("init", "--controller", "linuxcnc")
    assert code == 0
    text = text.replace('[[axes]]\nname = "Z"', '[[axes]]\nname = "Z"\nlink = { node_id = 3 }')
    path = tmp_path / "machine.toml"
    path.write_text(text, encoding="utf-8")
    return path


def test_writes_the_golden_twincat_table(results_file: Path, tmp_path: Path) -> None:
    target = tmp_path / "X.lis"
    code, out, err = run(
        "compensation", results_file, "--controller", "twincat", "--axis", "X", "-o", target
    )
    assert code == 0, err
    assert f"wrote {target}" in out
    assert target.read_text(encoding="utf-8") == (GOLDEN / "twincat_X.lis").read_text(
        encoding="utf-8"
    )


def test_prints_the_hal_snippet(results_file: Path) -> None:
    code, out, err = run(
        "compensation", results_file, "--controller", "linuxcnc", "--axis", "X", "--axis", "Z"
    )
    assert code == 0, err
    assert out == (GOLDEN / "linuxcnc.hal").read_text(encoding="utf-8")


def test_cia402_from_the_machine_file(results_file: Path, machine_file: Path) -> None:
    code, out, err = run(
        "compensation", results_file, "--controller", "cia402", "--machine", machine_file
    )
    assert code == 0, err
    assert 'axis = "Z"' in out and "node_id = 3" in out and "value = 113" in out


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("--controller", "twincat"), "error: axis Y: no friction model describes the positive"),
        (("--controller", "twincat", "--axis", "W"), "error: axis W was not analysed"),
        (("--controller", "fanuc"), "error: unknown controller 'fanuc' for a compensation"),
        (("--controller", "cia402", "--axis", "X"), "error: axis X is not vertical"),
        (("--controller", "cia402"), "error: axis Z: the SDO write needs the drive's node id"),
        (("--controller", "linuxcnc", "--axis", "X", "--points", "20"), "outside 5…16"),
        (("--controller", "twincat", "--axis", "X", "--units-per-a", "0"), "--units-per-a 0"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(
    results_file: Path, args: tuple[str, ...], message: str
) -> None:
    code, out, err = run("compensation", results_file, *args)
    assert code == 2
    assert err.startswith("error: ") and message in err and err.count("\n") == 1, err
    assert "Traceback" not in err and out == ""


def test_not_a_results_file(tmp_path: Path) -> None:
    path = tmp_path / "x.json"
    path.write_text("{}", encoding="utf-8")
    code, _, err = run("compensation", path, "--controller", "twincat")
    assert code == 2 and err.startswith("error:") and "not an ncmeasure results file" in err


def test_help_teaches() -> None:
    code, out, _ = run("compensation", "--help")
    assert code == 0
    for word in ("twincat", "linuxcnc", "cia402", "0x60B2", "--points", "--units-per-a"):
        assert word in out
