"""Start-up: every command imports what it works with, when it works with it.

``ncmeasure --version`` and ``--help`` import only the command line itself; a command's
``--help`` no more than typer needs; a command that runs imports the packages of its
own group only (scipy where a fit runs, matplotlib where a plot is drawn, SQLAlchemy
for the store, FastAPI for ``serve``, the bus libraries for acquisition, Jinja where a
template is rendered). What a command imports is counted, not timed: ``python -X
importtime`` names every module a process imports, whatever else the machine is doing.
"""

from __future__ import annotations

import os
import queue
import re
import signal
import subprocess
import sys
import tempfile
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

#: Packages a command imports only when it works with them.
HEAVY = ("numpy", "scipy", "pandas", "pydantic", "jinja2", "can", "canopen", "pymodbus",
         "asammdf", "matplotlib", "sqlalchemy", "alembic", "fastapi", "uvicorn")  # fmt: skip
WAIT_S = 120.0
"""The longest wait for one command: generous, for a loaded machine."""


def _names(importtime: str) -> set[str]:
    """The top-level names of the modules in ``-X importtime`` output."""
    names = set()
    for line in importtime.splitlines():
        if line.startswith("import time:") and "|" in line:
            names.add(line.rsplit("|", 1)[1].strip().split(".")[0])
    return names


def imported(*args: str, cwd: Path | None = None, codes: tuple[int, ...] = (0,)) -> set[str]:
    """The top-level names of the modules ``ncmeasure ARGS`` imports (it ends with ``codes``)."""
    # A relative PYTHONPATH (PYTHONPATH=src) would name another folder from cwd.
    paths = os.environ.get("PYTHONPATH", "").split(os.pathsep)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(str(Path(p).resolve()) for p in paths if p)}
    done = subprocess.run(
        [sys.executable, "-X", "importtime", "-m", "ncmeasure", *args],
        capture_output=True, text=True, timeout=WAIT_S, cwd=cwd, env=env,
    )  # fmt: skip
    lines = [line for line in done.stderr.splitlines() if not line.startswith("import time:")]
    assert done.returncode in codes, "\n".join(lines)
    return _names(done.stderr)


@pytest.mark.parametrize(
    ("args", "allowed"),
    [
        (("--version",), set()),
        (("--help",), set()),
        (("generate", "--help"), set()),  # typer converts no value there: no pydantic
        (("store", "show", "--help"), set()),
    ],
)
def test_version_and_help_import_no_heavy_package(args: tuple[str, ...], allowed: set[str]) -> None:
    loaded = imported(*args)
    assert "ncmeasure" in loaded  # the parse saw the imports at all
    assert not loaded & (set(HEAVY) - allowed), sorted(loaded & set(HEAVY))


def test_version_answers_before_the_command_line_is_imported() -> None:
    loaded = imported("--version")
    assert "ncmeasure" in loaded
    assert not loaded & {"typer", "click", "rich"}, sorted(loaded & {"typer", "click", "rich"})


def test_help_is_plain_and_imports_no_rich() -> None:
    # typer's rich help would import rich and markdown-it: half of --help's start-up.
    loaded = imported("--help")
    assert "typer" in loaded
    assert not loaded & {"rich", "markdown_it"}, sorted(loaded & {"rich", "markdown_it"})


def test_version_is_the_same_through_both_paths() -> None:
    from typer.testing import CliRunner

    from ncmeasure._version import __version__
    from ncmeasure.cli import app

    fast = subprocess.run(
        [sys.executable, "-m", "ncmeasure", "--version"],
        capture_output=True, text=True, timeout=120, check=True,
    )  # fmt: skip
    # "--debug --version" is not the fast path: typer's eager option answers it.
    full = CliRunner().invoke(app, ["--debug", "--version"])
    assert fast.stdout == full.output == f"ncmeasure {__version__}\n"


def test_the_public_api_is_still_there() -> None:
    import ncmeasure

    assert callable(ncmeasure.load_machine) and callable(ncmeasure.generate_programs)
    assert ncmeasure.Schedule.__name__ == "Schedule"
    with pytest.raises(AttributeError, match="no attribute 'nonsense'"):
        _ = ncmeasure.nonsense  # type: ignore[attr-defined]
    assert set(ncmeasure.__all__) <= set(dir(ncmeasure))


def test_python_can_without_mdf_support_leaves_asammdf_importable() -> None:
    code = (
        "import sys\n"
        "from ncmeasure.cli._startup import CanWithoutMdf\n"
        "sys.meta_path.insert(0, CanWithoutMdf())\n"
        "import can\n"
        "assert 'asammdf' not in sys.modules, 'python-can loaded asammdf'\n"
        "assert not any(isinstance(f, CanWithoutMdf) for f in sys.meta_path)\n"
        "import importlib.util\n"
        "if importlib.util.find_spec('asammdf') is not None:\n"
        "    import asammdf\n"
        "    assert asammdf.MDF is not None\n"
        "print(can.Message(arbitration_id=0x181, data=b'\\x01').arbitration_id)\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert done.stdout == "385\n"


def test_the_trace_importers_load_python_can_only_for_a_can_log() -> None:
    code = "import sys, ncmeasure.traces; print(' '.join(sorted(sys.modules)))"
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    )  # fmt: skip
    loaded = {name.split(".")[0] for name in done.stdout.split()}
    assert "ncmeasure" in loaded
    assert not loaded & {"can", "canopen", "pymodbus"}, sorted(loaded & {"can", "canopen"})


HELP_SCRIPT = """
import contextlib, io, sys
import typer.main
from ncmeasure.cli import app

HEAVY = set(sys.argv[1].split())
root = typer.main.get_command(app)


def paths(command, prefix):
    for name, sub in sorted(getattr(command, "commands", {}).items()):
        yield (*prefix, name)
        yield from paths(sub, (*prefix, name))


for path in paths(root, ()):
    with contextlib.redirect_stdout(io.StringIO()):
        root.main([*path, "--help"], prog_name="ncmeasure", standalone_mode=False)
    loaded = sorted(HEAVY & {name.split(".")[0] for name in sys.modules})
    print(" ".join(path), *loaded, sep="|")
"""


def test_every_command_help_imports_no_heavy_package() -> None:
    """The help of every command and subcommand, in one process, one after the other: a
    package appears on the line of the first command that imported it."""
    done = subprocess.run(
        [sys.executable, "-c", HELP_SCRIPT, " ".join(HEAVY)],
        capture_output=True, text=True, timeout=WAIT_S, check=True,
    )  # fmt: skip
    lines = [line.split("|") for line in done.stdout.splitlines()]
    commands = {line[0] for line in lines}
    assert {"init", "store show", "serve", "publish opcua", "schema machine"} <= commands
    assert len(commands) >= 30, sorted(commands)
    # pydantic too: typer's TypeAdapters are built only for a value that is there
    heavy = {line[0]: set(line[1:]) for line in lines}
    assert not any(heavy.values()), {name: found for name, found in heavy.items() if found}


COMMAND_MODULES = {
    f"ncmeasure.cli.{name}"
    for name in ("analysis", "compensation", "demo", "measure", "program", "publish", "record",
                 "serve", "store", "traces")
}  # fmt: skip


MODULES_SCRIPT = """
import sys
from ncmeasure.__main__ import main

sys.argv = ["ncmeasure", *sys.argv[1:]]
try:
    main()
finally:
    print(*sorted(sys.modules), file=sys.stderr)
"""


def modules_of(*args: str) -> set[str]:
    """The full names of the modules ``ncmeasure ARGS`` has imported when it ends (those
    ``importlib.import_module`` imports too, which ``-X importtime`` does not name)."""
    done = subprocess.run(
        [sys.executable, "-c", MODULES_SCRIPT, *args],
        capture_output=True, text=True, timeout=WAIT_S,
    )  # fmt: skip
    assert done.returncode in (0, 2), done.stderr
    return set(done.stderr.splitlines()[-1].split())


@pytest.mark.parametrize(
    ("args", "module"),
    [
        (("init", "--help"), "program"),
        (("--debug", "store", "show", "--help"), "store"),
        (("schema", "machine"), "program"),
        (("publish", "--help"), "publish"),
    ],
)
def test_a_command_registers_its_own_module_only(args: tuple[str, ...], module: str) -> None:
    loaded = modules_of(*args) & COMMAND_MODULES
    assert loaded == {f"ncmeasure.cli.{module}"}


@pytest.mark.parametrize("args", [("--help",), ("nosuch",), ()])
def test_the_list_of_commands_registers_every_module(args: tuple[str, ...]) -> None:
    # no command, or not one of ours: the full list (click's "No such command" suggests)
    loaded = modules_of(*args)
    assert loaded >= COMMAND_MODULES, sorted(COMMAND_MODULES - loaded)


def test_every_command_is_found_in_the_module_that_registers_it() -> None:
    import typer.main

    from ncmeasure.cli import _MODULES, app

    found = {}
    for name, command in typer.main.get_command(app).commands.items():  # type: ignore[attr-defined]
        for each in getattr(command, "commands", {}).values() or [command]:
            found[name] = each.callback.__module__
    assert {name: f"ncmeasure.cli.{module}" for name, module in _MODULES.items()} == found


def test_the_command_word_is_the_first_word_that_is_not_an_option() -> None:
    from ncmeasure.cli import _invoked

    assert _invoked(["--debug", "store", "show", "M1"]) == "store"
    assert _invoked(["simulate-drive", "--help"]) == "record"
    assert _invoked(["--help"]) is None
    assert _invoked(["nosuch", "init"]) is None
    assert _invoked(["--", "init"]) is None


VALUES: dict[str, list[object]] = {
    "str": ["M17", "", "ä b", "a\udcff"],
    "Path": ["x.toml", "", ".", "/", "a//b/", "~/x", "nothere/y.csv"],
    "int": [0, 1, 5, 10_000, 65_535],
    "float": [0.0, 1.5, -2.0],
    "bool": [True, False],
}
"""Values an option may get, from the command line (text) or as a default (a number)."""


def test_option_values_convert_as_typer_converts_them(tmp_path: Path) -> None:
    """Every option and argument of every command, every value of its type in
    :data:`VALUES` (one at a time and as a list): the same result as typer's own
    TypeAdapter, or the same error."""
    import typer
    import typer.main
    from typer import _coercion

    from ncmeasure.cli import app

    (tmp_path / "x.toml").write_text("")
    ctx = typer.Context(typer.main.get_command(app))
    root = typer.main.get_command(app)
    checked = 0
    for command, param, descriptor, values in _typed_params(root):
        ours = param.get_runtime_param()
        theirs = _coercion.build_runtime_param(descriptor)
        assert type(ours).__name__ == "Common"
        for value in values:
            tries = [[value], (value, value)] if descriptor.is_list else [value]
            for given in tries:
                assert _outcome(ours, given, param, ctx, tmp_path) == _outcome(
                    theirs, given, param, ctx, tmp_path
                ), (command.name, param.name, given)
                checked += 1
    assert checked > 500


def test_a_typer_whose_private_parts_differ_converts_with_its_own_adapter(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Where the quick conversion meets something it does not know (typer's private parts
    changed), typer's own adapter converts: the same results and errors, no traceback."""
    import typer
    import typer.main
    from typer import _coercion

    from ncmeasure.cli import _startup, app

    def other_typer(*args: object, **kwargs: object) -> object:
        raise RuntimeError("another typer")

    monkeypatch.setattr(_startup, "_common_value", other_typer)
    (tmp_path / "x.toml").write_text("")
    root = typer.main.get_command(app)
    ctx = typer.Context(root)
    checked = 0
    for command, param, descriptor, values in _typed_params(root):
        theirs = _coercion.build_runtime_param(descriptor)
        for value in values[:2]:
            given = [value] if descriptor.is_list else value
            assert _outcome(param.get_runtime_param(), given, param, ctx, tmp_path) == (
                _outcome(theirs, given, param, ctx, tmp_path)
            ), (command.name, param.name, given)
            checked += 1
    assert checked > 100


def _typed_params(root: object) -> Iterator[tuple[Any, Any, Any, list[Any]]]:
    """Every option and argument of every command that typer converts by its type: the
    command, the parameter, its type descriptor and the :data:`VALUES` of its (item) type."""
    for command in _every_command(root):
        for param in command.params:  # type: ignore[attr-defined]
            descriptor = getattr(param, "type_descriptor", None)
            if descriptor is None:
                continue
            item = descriptor.annotation
            if descriptor.is_list:
                (item,) = typer_args(descriptor.annotation)
            yield command, param, descriptor, VALUES.get(getattr(item, "__name__", ""), [])


def typer_args(annotation: object) -> tuple[object, ...]:
    from typing import get_args

    return get_args(annotation)


def _every_command(group: object) -> list[object]:
    found = []
    for sub in getattr(group, "commands", {}).values():
        found.append(sub)
        found.extend(_every_command(sub))
    return found


def _outcome(runtime: object, value: object, param: object, ctx: object, cwd: Path) -> object:
    """What converting ``value`` gives (its type and value) or raises (type and message)."""
    here = Path.cwd()
    os.chdir(cwd)
    try:
        result = runtime.coerce(value, param=param, ctx=ctx)  # type: ignore[attr-defined]
    except Exception as exc:  # the error itself is what is compared
        return ("error", type(exc).__name__, str(exc))
    finally:
        os.chdir(here)
    return (type(result).__name__, result)


@dataclass(frozen=True)
class Files:
    """A folder of inputs for real commands: a machine file, generated programs, a
    recording, two results files and a SQLite store with one machine measured twice."""

    folder: Path
    store: str


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> Files:
    from typer.testing import CliRunner

    from ncmeasure.analysis.analyze import analyze
    from ncmeasure.cli import app
    from ncmeasure.formats.results import write_results
    from ncmeasure.sim.synthetic import SyntheticAxis, geometric_velocities, synthetic_recording

    folder = tmp_path_factory.mktemp("startup")
    runner = CliRunner()
    init = runner.invoke(app, ["init"])
    assert init.exit_code == 0, init.output
    (folder / "machine.toml").write_text(init.stdout)
    generated = runner.invoke(app, ["generate", str(folder / "machine.toml"), "-o",
                                    str(folder / "programs"), "--quiet"])  # fmt: skip
    assert generated.exit_code == 0, generated.output
    velocities = geometric_velocities(10.0, 15000.0, 8)
    store = f"sqlite:///{folder / 'fleet.db'}"
    for name, coulomb, seed in (("delivery", 2.0, 1), ("service", 2.6, 2)):
        axes = [SyntheticAxis(name="X", coulomb=coulomb, velocities_mm_min=velocities)]
        recording, schedule = synthetic_recording(folder / f"{name}-run", axes, seed=seed)
        write_results(analyze(recording, schedule=schedule), folder / f"{name}.json")
        added = runner.invoke(app, ["store", "add", str(folder / f"{name}.json"), "--serial",
                                    "M1", "--label", name, "--store", store])  # fmt: skip
        assert added.exit_code == 0, added.output
    return Files(folder, store)


#: Bus libraries: acquisition only.
LINKS = {"can", "canopen", "pymodbus"}
#: Packages of the web server: ``serve`` only.
WEB = {"fastapi", "uvicorn"}
STORE = {"sqlalchemy", "alembic"}


CASES: list[tuple[tuple[str, ...], tuple[int, ...], set[str]]] = [
    # programs: the dialects and the machine file; Jinja and the planner where rendered
    # (init names a built-in dialect without loading its pydantic models)
    (("init",), (0,),
     {"pydantic", "numpy", "jinja2", "scipy", "matplotlib", *STORE, *WEB, *LINKS}),
    (("init", "--controller", "linuxcnc"), (0,),
     {"pydantic", "numpy", "jinja2", "scipy", "matplotlib", *STORE, *WEB, *LINKS}),
    # the built-in dialects listed from their files, the schemas from theirs: no pydantic
    (("controllers",), (0,),
     {"pydantic", "numpy", "jinja2", "scipy", "matplotlib", *STORE, *WEB, *LINKS}),
    (("controllers", "--details"), (0,),
     {"pydantic", "numpy", "jinja2", "scipy", "matplotlib", *STORE, *WEB, *LINKS}),
    (("schema", "machine"), (0,),
     {"pydantic", "numpy", "jinja2", "scipy", "matplotlib", *STORE, *WEB}),
    (("schema", "results"), (0,),
     {"pydantic", "numpy", "jinja2", "scipy", "matplotlib", *STORE, *WEB}),
    (("check", "programs"), (0,), {"jinja2", "scipy", "matplotlib", *STORE, *WEB, *LINKS}),
    (("plan", "machine.toml"), (0,), {"scipy", "matplotlib", *STORE, *WEB, *LINKS}),
    # files: numpy and the recording
    (("export", "delivery-run", "-o", "x.csv"), (0,),
     {"scipy", "matplotlib", "jinja2", *STORE, *WEB, *LINKS}),
    # the analysis: scipy where a fit runs, matplotlib only for a PNG plot
    (("analyze", "delivery-run", "-o", "again.json"), (0,),
     {"matplotlib", "jinja2", *STORE, *WEB, *LINKS}),
    # the report's figures are SVG written directly: no matplotlib
    (("analyze", "delivery-run", "-o", "reported.json", "--report", "reported.html"), (0,),
     {"matplotlib", *STORE, *WEB, *LINKS}),
    # quiet: no progress bar, so no rich
    (("analyze", "delivery-run", "-o", "quiet.json", "-q"), (0,),
     {"rich", "matplotlib", "jinja2", *STORE, *WEB, *LINKS}),
    (("compare", "delivery.json", "service.json"), (0, 1, 3),
     {"matplotlib", "jinja2", *STORE, *WEB, *LINKS}),
    (("simulate", "machine.toml"), (0,), {"scipy", "matplotlib", *STORE, *WEB, *LINKS}),
    (("compensation", "delivery.json", "--controller", "twincat", "--axis", "X", "-o",
      "x.lis"), (0,), {"scipy", "matplotlib", *STORE, *WEB, *LINKS}),
    # the store: SQLAlchemy, no fit, no plot unless drawn
    (("store", "list"), (0,), {"scipy", "matplotlib", "jinja2", *WEB, *LINKS}),
    (("store", "show", "M1"), (0,), {"scipy", "matplotlib", "jinja2", *WEB, *LINKS}),
    (("store", "trend", "M1", "--axis", "X"), (0,),
     {"scipy", "matplotlib", "jinja2", *WEB, *LINKS}),
    (("store", "export", "-o", "x.jsonl"), (0,),
     {"scipy", "matplotlib", "jinja2", *WEB, *LINKS}),
    # the report's trends are SVG written directly: no matplotlib either
    (("store", "report", "-o", "fleet.html"), (0, 1, 3), {"scipy", "matplotlib", *WEB, *LINKS}),
    (("store", "report", "-o", "fleet.html", "--trends", "0"), (0, 1, 3),
     {"scipy", "matplotlib", *WEB, *LINKS}),
]  # fmt: skip
"""Per command: its arguments (run in the folder of :func:`files`), the exit codes it may
end with, and the packages it must not import."""


@pytest.mark.parametrize(("args", "codes", "forbidden"), CASES, ids=[" ".join(c[0]) for c in CASES])
def test_a_command_imports_its_own_group_only(
    files: Files, args: tuple[str, ...], codes: tuple[int, ...], forbidden: set[str]
) -> None:
    store = ("--store", files.store) if args[0] == "store" else ()
    loaded = imported(*args, *store, cwd=files.folder, codes=codes)
    assert "ncmeasure" in loaded
    assert not loaded & forbidden, sorted(loaded & forbidden)


@pytest.mark.parametrize(
    ("args", "forbidden"),
    [
        # the programs and schedule.json: no machine file read, so not its models
        (("check", "programs"), {"ncmeasure.config"}),
        # a recording's own models, not the machine file's
        (("export", "delivery-run", "-o", "x.csv"), {"ncmeasure.config"}),
        (("export", "delivery-run", "-o", "x.mf4", "--format", "mdf4"), {"ncmeasure.config"}),
    ],
    ids=["check", "export csv", "export mdf4"],
)
def test_a_command_imports_no_models_it_does_not_use(
    files: Files, args: tuple[str, ...], forbidden: set[str]
) -> None:
    loaded = imported_modules(*args, cwd=files.folder)
    assert "ncmeasure.cli" in loaded
    assert not loaded & forbidden, sorted(loaded & forbidden)


def imported_modules(*args: str, cwd: Path) -> set[str]:
    """The full names of the modules ``ncmeasure ARGS``, run in ``cwd``, has imported when
    it ends (``importlib.import_module``'s too)."""
    paths = os.environ.get("PYTHONPATH", "").split(os.pathsep)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(str(Path(p).resolve()) for p in paths if p)}
    done = subprocess.run(
        [sys.executable, "-c", MODULES_SCRIPT, *args],
        capture_output=True, text=True, timeout=WAIT_S, cwd=cwd, env=env,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    return set(done.stderr.splitlines()[-1].split())


def test_the_list_of_controllers_is_the_one_their_models_give(tmp_path: Path) -> None:
    """``controllers`` reads a built-in dialect's file without its models, a user's own
    through them: copies of the built-ins (a user's folder hides a built-in of the same
    name) list the same, with and without ``--details``."""
    import shutil

    from typer.testing import CliRunner

    from ncmeasure.cli import app
    from ncmeasure.resources import builtin_dir

    for path in builtin_dir("controllers").glob("*.toml"):
        shutil.copy(path, tmp_path / path.name)
    runner = CliRunner()
    for details in ([], ["--details"]):
        builtin = runner.invoke(app, ["controllers", *details], env={"COLUMNS": "200"})
        own = runner.invoke(app, ["controllers", *details, "--controllers-dir", str(tmp_path)],
                            env={"COLUMNS": "200"})  # fmt: skip
        assert builtin.exit_code == own.exit_code == 0, builtin.output + own.output
        assert builtin.output == own.output
    assert "program memory: 512 kB" in builtin.output  # --details: the memory shown


def test_the_list_of_controllers_shows_what_the_models_hold() -> None:
    """Field by field, a built-in dialect as the list reads it and as its models hold it
    (the defaults of the models included: a file that leaves a field out)."""
    from ncmeasure.cli.program import _listed
    from ncmeasure.program import load_dialect
    from ncmeasure.resources import available_dialects

    dialects = available_dialects()
    assert len(dialects) >= 5
    for name, path in dialects.items():
        dialect = load_dialect(name)
        listed = _listed(name, path, ())
        assert listed == (
            dialect.title, dialect.names.main_file, dialect.names.sub_file,
            dialect.subprograms, dialect.marker.scope, dialect.marker.mechanism,
            dialect.options, dialect.memory.program_kb, dialect.memory.note,
            dialect.left_out,
        ), name  # fmt: skip
        assert [type(v) for v in listed.options.values()] == [
            type(v) for v in dialect.options.values()
        ]
        assert list(listed.left_out) == list(dialect.left_out)


def test_each_schema_file_is_its_models_schema(update_golden: bool) -> None:
    """``ncmeasure schema NAME`` prints the package's file of that format; each file is
    what its model gives (``pytest --update-golden`` writes them again after a change of
    the models)."""
    import importlib
    import json

    import ncmeasure
    from ncmeasure.cli.program import SCHEMAS, schema_text

    folder = Path(ncmeasure.__file__).parent / "data" / "schemas"
    for name, where in SCHEMAS.items():
        module, attribute = where.split(":")
        model = getattr(importlib.import_module(module), attribute)
        expected = json.dumps(model.model_json_schema(), indent=2) + "\n"
        if update_golden:
            (folder / f"{name}.json").write_text(expected, encoding="utf-8")
        assert schema_text(name) == expected, (
            f"data/schemas/{name}.json is not the schema of {where}: "
            "run pytest --update-golden tests/test_startup.py"
        )


def test_serve_starts_without_scipy_or_matplotlib(files: Files) -> None:
    """``serve`` until it says where it serves: FastAPI and the store, no fit, no plot;
    and its pages, plots included, draw without matplotlib."""
    import httpx2 as httpx

    pages = ["/", "/machines/M1", "/machines/M1/axes/X", "/machines/M1/axes/X/trend.svg"]
    with tempfile.TemporaryFile("w+") as err:  # a pipe would fill up and block the server
        process = subprocess.Popen(
            [sys.executable, "-X", "importtime", "-m", "ncmeasure", "serve", "--store",
             files.store, "--port", "0"],
            stdout=subprocess.PIPE, stderr=err, text=True,
            env={**os.environ, "COLUMNS": "200"},
        )  # fmt: skip
        lines: queue.Queue[str] = queue.Queue()
        assert process.stdout is not None
        threading.Thread(target=lambda: lines.put(process.stdout.readline()), daemon=True).start()
        try:
            first = lines.get(timeout=WAIT_S)
            err.seek(0)
            started = _names(err.read())
            at = re.search(r" at (http://\S+?)/? ", first)
            codes = [
                httpx.get(at.group(1) + page, timeout=WAIT_S).status_code
                for page in (pages if at else [])
            ]
        finally:
            process.send_signal(signal.SIGTERM)
            try:
                process.wait(timeout=WAIT_S)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait(timeout=WAIT_S)
        err.seek(0)
        loaded = _names(err.read())
    assert first.startswith("serving "), first
    assert {"fastapi", "sqlalchemy"} <= started
    assert not started & {"scipy", "matplotlib", *LINKS}, sorted(started & {"scipy", "matplotlib"})
    assert codes == [200] * len(pages)
    assert "matplotlib" not in loaded


def test_init_takes_a_builtin_dialect_as_read_because_each_one_loads() -> None:
    """``init`` names a built-in controller without loading it: each one must load."""
    from ncmeasure.program import load_dialect
    from ncmeasure.resources import available_dialects, builtin_dir

    builtins = sorted(builtin_dir("controllers").glob("*.toml"))
    assert len(builtins) >= 5
    for path in builtins:
        assert available_dialects()[path.stem] == path
        assert load_dialect(path.stem).name == path.stem


def test_init_still_reads_and_checks_a_dialect_of_the_users_own(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from ncmeasure.cli import app
    from ncmeasure.resources import builtin_dir

    # a user's file of a built-in's name hides the built-in, and is checked
    (tmp_path / "fanuc.toml").write_text('name = "fanuc"\n', encoding="utf-8")
    done = CliRunner().invoke(app, ["init", "--controller", "fanuc", "--controllers-dir",
                                    str(tmp_path)])  # fmt: skip
    assert done.exit_code == 2
    assert "is not a valid controller definition" in done.output
    # a user's valid file under its own name: the example names it
    text = (builtin_dir("controllers") / "linuxcnc.toml").read_text(encoding="utf-8")
    (tmp_path / "mine.toml").write_text(
        text.replace('name = "linuxcnc"', 'name = "mine"'), encoding="utf-8"
    )
    done = CliRunner().invoke(app, ["init", "--controller", "mine", "--controllers-dir",
                                    str(tmp_path)])  # fmt: skip
    assert done.exit_code == 0, done.output
    assert 'controller = "mine"' in done.output


def test_the_command_line_imports_click_only_through_typer() -> None:
    """A typer that carries its own copy of click (0.2x): the command line does not import
    click itself (its import is a tenth of a command's start-up)."""
    import importlib.util

    if importlib.util.find_spec("typer._click") is None:
        pytest.skip("this typer imports click itself")
    loaded = imported("init")
    assert "typer" in loaded
    assert "click" not in loaded


def test_a_value_typer_finds_wrong_is_its_error_at_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """The quick conversion's own click error (typer's path checks) is typer's message as
    it stands: no second conversion through typer's adapter (pydantic)."""
    import typer
    import typer.main

    from ncmeasure.cli import _startup, app

    error = _bad_parameter()

    def wrong(*args: object, **kwargs: object) -> object:
        raise error("no such thing")

    monkeypatch.setattr(_startup, "_common_value", wrong)
    root = typer.main.get_command(app)
    ctx = typer.Context(root)
    found = [(p, d) for _, p, d, _ in _typed_params(root) if d.annotation is Path]
    assert found
    param, _ = found[0]
    runtime = param.get_runtime_param()
    with pytest.raises(error, match="no such thing"):
        runtime.coerce("x.toml", param=param, ctx=ctx)
    assert runtime.built == []


def _bad_parameter() -> type[Exception]:
    """The BadParameter of the click typer converts with."""
    try:
        from typer._click.exceptions import BadParameter
    except ImportError:  # a typer that imports click itself
        from click import BadParameter
    return BadParameter
