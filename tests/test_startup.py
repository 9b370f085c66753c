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
import signal
import subprocess
import sys
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path

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
        (("generate", "--help"), {"pydantic"}),  # typer's own coercion of the arguments
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
    # pydantic: typer's own coercion of the arguments
    heavy = {line[0]: set(line[1:]) - {"pydantic"} for line in lines}
    assert not any(heavy.values()), {name: found for name, found in heavy.items() if found}


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
    (("init",), (0,), {"numpy", "jinja2", "scipy", "matplotlib", *STORE, *WEB, *LINKS}),
    (("controllers",), (0,), {"numpy", "jinja2", "scipy", "matplotlib", *STORE, *WEB, *LINKS}),
    (("schema", "machine"), (0,), {"numpy", "jinja2", "scipy", "matplotlib", *STORE, *WEB}),
    (("check", "programs"), (0,), {"jinja2", "scipy", "matplotlib", *STORE, *WEB, *LINKS}),
    (("plan", "machine.toml"), (0,), {"scipy", "matplotlib", *STORE, *WEB, *LINKS}),
    # files: numpy and the recording
    (("export", "delivery-run", "-o", "x.csv"), (0,),
     {"scipy", "matplotlib", "jinja2", *STORE, *WEB, *LINKS}),
    # the analysis: scipy where a fit runs, matplotlib only for a report or a plot
    (("analyze", "delivery-run", "-o", "again.json"), (0,),
     {"matplotlib", "jinja2", *STORE, *WEB, *LINKS}),
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
    (("store", "report", "-o", "fleet.html"), (0, 1, 3), {"scipy", *WEB, *LINKS}),
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


def test_serve_starts_without_scipy_or_matplotlib(files: Files) -> None:
    """``serve`` until it says where it serves: FastAPI and the store, no fit, no plot
    (matplotlib comes with the first page that draws one)."""
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
    assert {"fastapi", "sqlalchemy"} <= loaded
    assert not loaded & {"scipy", "matplotlib", *LINKS}, sorted(loaded & {"scipy", "matplotlib"})
