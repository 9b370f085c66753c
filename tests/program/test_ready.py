"""The main program waits for the recorder's ready signal where the machine file asks."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from ncmeasure.config import config_hash, parse_machine
from ncmeasure.errors import ConfigError, ProgramCheckError, ProgramError
from ncmeasure.program import generate_programs
from ncmeasure.program.check import check_programs
from ncmeasure.program.reader import ReadyWait, read_programs
from tests.conftest import FIXED_TIME, example_data, small_data


def ready_data(controller: str = "linuxcnc", **machine: Any) -> dict[str, Any]:
    data = small_data(controller)
    data["machine"].update({"ready_input": 2, "ready_timeout_s": 45.0, **machine})
    return data


def written(tmp_path: Path, data: dict[str, Any]) -> Path:
    result = generate_programs(parse_machine(data), generated=FIXED_TIME)
    result.write(tmp_path)
    return tmp_path / result.main_file


def test_the_keys_at_their_defaults_keep_the_hash() -> None:
    data = example_data("linuxcnc")
    before = config_hash(parse_machine(data))
    data["machine"]["ready_timeout_s"] = 60.0
    data["machine"].pop("ready_timeout_s")
    assert config_hash(parse_machine(data)) == before
    data["machine"]["ready_input"] = 1
    assert config_hash(parse_machine(data)) != before


def test_a_time_out_without_an_input_is_half_a_configuration() -> None:
    data = example_data("linuxcnc")
    data["machine"]["ready_timeout_s"] = 30.0
    with pytest.raises(ConfigError) as info:
        parse_machine(data)
    assert "machine.ready_timeout_s" in str(info.value.problems)


def test_an_input_without_the_links_output_is_half_a_configuration() -> None:
    data = ready_data()
    data["link"] = {"type": "canopen", "channel": "can0"}
    for index, axis in enumerate(data["axes"]):
        axis["link"] = {"node_id": index + 1, "increments_per_rev": 10_000}
    with pytest.raises(ConfigError, match="ready_output_bit"):
        parse_machine(data)


def test_an_output_without_the_input_is_half_a_configuration() -> None:
    data = small_data("linuxcnc")
    data["link"] = {"type": "modbus", "register_map": "generic"}
    data["axes"][0]["link"] = {"unit_id": 1, "ready": {"function": "coil", "address": 3}}
    with pytest.raises(ConfigError) as info:
        parse_machine(data)
    assert any("axes[0].link.ready" in p for p in info.value.problems)


def test_linuxcnc_waits_after_the_confirmation_before_the_first_move(tmp_path: Path) -> None:
    main = written(tmp_path, ready_data())
    text = main.read_text()
    assert "M66 P2 L3 Q45\no100 if [#5399 LT 0]\n(MSG,RECORDER NOT READY)\nM2\no100 endif\n" in text
    assert text.index("M0\n") < text.index("M66") < text.index("G53 G0")
    trace = read_programs(
        generate_programs(parse_machine(ready_data()), generated=FIXED_TIME).dialect,
        tmp_path,
        main.name,
        {"X", "Y", "Z"},
    )
    waits = [s for s in trace.steps if isinstance(s, ReadyWait)]
    assert [(w.input, w.timeout_s) for w in waits] == [(2, 45.0)]
    assert trace.motions  # the time-out branch is not taken: the program goes on
    check_programs(tmp_path)


def test_a_wait_after_a_move_is_refused(tmp_path: Path) -> None:
    main = written(tmp_path, ready_data())
    lines = main.read_text().split("\n")
    start = lines.index("M66 P2 L3 Q45")
    block = lines[start - 1 : start + 5]
    del lines[start - 1 : start + 5]
    first_move = next(i for i, line in enumerate(lines) if line.startswith("G53 G0"))
    lines[first_move + 1 : first_move + 1] = block
    main.write_text("\n".join(lines))
    with pytest.raises(ProgramCheckError) as info:
        check_programs(tmp_path)
    assert "moves before the program waits" in str(info.value.problems)


def test_a_wait_without_a_time_out_is_refused(tmp_path: Path) -> None:
    main = written(tmp_path, ready_data())
    main.write_text(main.read_text().replace("M66 P2 L3 Q45", "M66 P2 L3"))
    with pytest.raises((ProgramCheckError, ProgramError), match="time-out"):
        check_programs(tmp_path)


def test_a_wait_without_its_time_out_branch_is_refused(tmp_path: Path) -> None:
    main = written(tmp_path, ready_data())
    main.write_text(main.read_text().replace("(MSG,RECORDER NOT READY)\nM2\n", ""))
    with pytest.raises((ProgramCheckError, ProgramError), match="time-out branch"):
        check_programs(tmp_path)


@pytest.mark.parametrize("controller", ["sinumerik-840d", "fanuc", "heidenhain-iso", "twincat"])
def test_dialects_without_a_verified_wait_refuse_the_key(controller: str) -> None:
    with pytest.raises(ConfigError) as info:
        generate_programs(parse_machine(ready_data(controller)), generated=FIXED_TIME)
    assert any("cycle start once the recorder waits" in p for p in info.value.problems)


def test_an_input_the_control_lacks_is_refused() -> None:
    with pytest.raises(ConfigError, match="digital input"):
        generate_programs(parse_machine(ready_data(ready_input=64)), generated=FIXED_TIME)


def test_the_setup_sheet_says_how_the_program_waits(tmp_path: Path) -> None:
    written(tmp_path, ready_data())
    sheet = (tmp_path / "SETUP.md").read_text(encoding="utf-8")
    assert (
        "waits up to 45 s before its first move for the recorder's ready signal on input 2" in sheet
    )
    assert "motion.digital-in-NN" in sheet
    plain = tmp_path / "plain"
    written(plain, small_data("linuxcnc"))
    assert "ready signal" not in (plain / "SETUP.md").read_text(encoding="utf-8")
