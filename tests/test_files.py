"""Replacing a file whole through an exclusive temporary file beside it."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from ncmeasure.errors import OutputError
from ncmeasure.files import replace_binary, replace_text, write_whole


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


def test_write_whole_writes_text_or_bytes_and_creates_the_folder_when_asked(
    tmp_path: Path,
) -> None:
    text = write_whole(tmp_path / "a" / "b" / "out.json", "{}\n", parents=True, fsync=True)
    assert text == tmp_path / "a" / "b" / "out.json"
    assert text.read_bytes() == b"{}\n"
    binary = write_whole(tmp_path / "out.png", b"\x89PNG\r\n")
    assert binary.read_bytes() == b"\x89PNG\r\n"
    with pytest.raises(OutputError, match="cannot be written"):
        write_whole(tmp_path / "missing" / "out.json", "{}")  # no parents: no folder


def test_write_whole_names_the_file_and_leaves_nothing_behind(tmp_path: Path) -> None:
    (tmp_path / "blocker").write_text("a file, not a folder", encoding="utf-8")
    with pytest.raises(OutputError) as caught:
        write_whole(tmp_path / "blocker" / "out.txt", "new", parents=True)
    assert str(caught.value).startswith(f"{tmp_path / 'blocker' / 'out.txt'}: cannot be written (")
    folder = tmp_path / "results.json"  # a folder where the file is to go
    folder.mkdir()
    (folder / "keep").write_text("kept", encoding="utf-8")
    with pytest.raises(OutputError, match=r"results\.json: cannot be written \(Is a directory"):
        write_whole(folder, "{}")
    assert (folder / "keep").read_text(encoding="utf-8") == "kept"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blocker", "results.json"]
