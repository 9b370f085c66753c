"""The file of `ncmeasure compensation --controller cia402`, read back for `apply-compensation`."""

from __future__ import annotations

import tomllib
from pathlib import Path

from ncmeasure.formats.offsets import OffsetWrite, read_offset_file
from ncmeasure.formats.results import write_results
from tests.compensation.example import example_results
from tests.links.test_canopen_offsets import VALUE, machine_text, run


def test_the_file_compensation_writes_is_what_apply_reads(tmp_path: Path) -> None:
    machine = tmp_path / "machine.toml"
    machine.write_text(machine_text("any-bus"), encoding="utf-8")
    results = write_results(example_results(), tmp_path / "run1.results.json")
    offsets = tmp_path / "z-offset.toml"
    code, _, err = run("compensation", results, "--controller", "cia402",
                       "--machine", machine, "-o", offsets)  # fmt: skip
    assert code == 0, err
    assert read_offset_file(offsets) == [OffsetWrite("Z", 3, VALUE)]
    assert tomllib.loads(offsets.read_text(encoding="utf-8"))["sdo_write"][0]["value"] == VALUE
