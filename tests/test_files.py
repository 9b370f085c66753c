"""Replacing a file whole through an exclusive temporary file beside it."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from ncmeasure.files import replace_binary, replace_text


def test_the_file_is_replaced_whole_with_the_usual_permissions(tmp_path: Path) -> None:
    target = tmp_path / "out.txt"
    target.write_text("old", encoding="utf-8")
    previous = os.umask(0o022)
    try:
        with replace_text(target, newline="\n", fsync=True) as file:
            file.write("new\n")
            assert target.read_text(encoding="utf-8") == "old"  # not yet replaced
        with replace_binary(tmp_path / "out.bin") as binary:
            binary.write(b"\x00\x01")
    finally:
        os.umask(previous)
    assert target.read_text(encoding="utf-8") == "new\n"
    assert (tmp_path / "out.bin").read_bytes() == b"\x00\x01"
    assert stat.S_IMODE(target.stat().st_mode) == 0o644  # 0o666 less the umask, not 0o600
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.bin", "out.txt"]


def test_a_failure_leaves_the_target_and_no_temporary_file(tmp_path: Path) -> None:
    target = tmp_path / "out.txt"
    target.write_text("old", encoding="utf-8")
    with pytest.raises(RuntimeError), replace_text(target) as file:
        file.write("half")
        raise RuntimeError("stop")
    assert target.read_text(encoding="utf-8") == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]


def test_a_symlink_at_the_target_is_replaced_not_followed(tmp_path: Path) -> None:
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me", encoding="utf-8")
    (tmp_path / "out.txt").symlink_to(victim)
    with replace_text(tmp_path / "out.txt") as file:
        file.write("new")
    assert victim.read_text(encoding="utf-8") == "keep me"
    assert not (tmp_path / "out.txt").is_symlink()
    assert (tmp_path / "out.txt").read_text(encoding="utf-8") == "new"
