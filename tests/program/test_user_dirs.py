"""User folders for controllers and templates are searched before the built-in ones."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

from ncmeasure.config import MachineConfig
from ncmeasure.errors import DialectError
from ncmeasure.program import available_dialects, check_programs, generate_programs
from ncmeasure.program.render import generation_time
from ncmeasure.resources import builtin_dir
from tests.conftest import FIXED_TIME

Make = Callable[..., MachineConfig]


def test_own_template_replaces_the_builtin_one(make_config: Make, tmp_path: Path) -> None:
    own = tmp_path / "templates" / "linuxcnc"
    own.mkdir(parents=True)
    main = (builtin_dir("templates") / "linuxcnc" / "main.j2").read_text()
    (own / "main.j2").write_text(main.replace("G64 P0.005", "G64 P0.001\n(our shop)"))
    result = generate_programs(
        make_config("linuxcnc", small=True),
        templates_dirs=[tmp_path / "templates"],
        generated=FIXED_TIME,
    )
    assert "(our shop)" in result.files["friction.ngc"]
    # the subprogram template still comes from the built-ins
    assert "o<friction_x> sub" in result.files["friction_x.ngc"]
    result.write(tmp_path / "out")
    assert check_programs(tmp_path / "out").ok


def test_own_dialect_beside_the_builtins(make_config: Make, tmp_path: Path) -> None:
    controllers = tmp_path / "controllers"
    controllers.mkdir()
    text = (builtin_dir("controllers") / "linuxcnc.toml").read_text()
    (controllers / "shopcnc.toml").write_text(text.replace('name = "linuxcnc"', 'name = "shopcnc"'))
    shutil.copytree(builtin_dir("templates") / "linuxcnc", tmp_path / "templates" / "shopcnc")
    assert "shopcnc" in available_dialects([controllers])
    data = make_config("linuxcnc", small=True).model_dump()
    data["machine"]["controller"] = "shopcnc"
    config = MachineConfig.model_validate(data)
    result = generate_programs(
        config,
        controllers_dirs=[controllers],
        templates_dirs=[tmp_path / "templates"],
        generated=FIXED_TIME,
    )
    result.write(tmp_path / "out")
    assert check_programs(tmp_path / "out", (controllers,)).ok
    with pytest.raises(DialectError, match="unknown controller 'shopcnc'"):
        generate_programs(config)


def test_broken_template_is_a_dialect_error(make_config: Make, tmp_path: Path) -> None:
    own = tmp_path / "linuxcnc"
    own.mkdir()
    (own / "main.j2").write_text("G0 {{ v.no_such_thing }}\n")
    result = generate_programs(make_config("linuxcnc", small=True), templates_dirs=[tmp_path])
    with pytest.raises(DialectError, match=r"template .*main.j2.*no_such_thing"):
        result.write(tmp_path / "out")
    assert not (tmp_path / "out").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["linuxcnc"], "no staging folder is left"


def test_source_date_epoch_fixes_the_header_date(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1768465800")
    assert generation_time() == FIXED_TIME


@pytest.mark.parametrize("kind", ["fifo", "device", "huge"])
def test_a_template_that_is_no_regular_file_is_an_error_not_a_fallback(
    kind: str,
    make_config: Make,
    tmp_path: Path,
    special_file: Callable[[str, Path], Path],
) -> None:
    own = tmp_path / "templates" / "linuxcnc"
    own.mkdir(parents=True)
    path = special_file(kind, own / "main.j2")
    result = generate_programs(
        make_config("linuxcnc", small=True), templates_dirs=[tmp_path / "templates"]
    )
    with pytest.raises(DialectError) as caught:
        result.write(tmp_path / "out")
    expected = "more than the 1 MiB" if kind == "huge" else "not a regular file"
    assert str(caught.value).startswith(f"{path}: ") and expected in str(caught.value)
    assert not (tmp_path / "out").exists()
