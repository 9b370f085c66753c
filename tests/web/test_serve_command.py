"""``ncmeasure serve`` as a user starts it: a process that serves until Ctrl-C or SIGTERM."""

from __future__ import annotations

import os
import queue
import re
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx2 as httpx
import pytest
from typer.testing import CliRunner

from ncmeasure.cli import app
from tests.web.conftest import TOKEN, WAIT_S, Fleet

runner = CliRunner()


class Served:
    """A running ``ncmeasure serve``: its process, its URL, what it printed."""

    def __init__(
        self, process: subprocess.Popen[str], first: str, lines: queue.Queue[str | None]
    ) -> None:
        found = re.search(r"at (http://\S+/)", first)
        assert found, first
        self.process = process
        self.first = first
        """The line saying where it serves."""
        self.url = found.group(1)
        self._lines = lines

    def stop(self, sig: signal.Signals = signal.SIGTERM) -> tuple[int, str, str]:
        """Send ``sig``; the exit code, the rest of stdout, and stderr."""
        self.process.send_signal(sig)
        code = self.process.wait(timeout=WAIT_S)
        out = []
        while (line := self._lines.get(timeout=WAIT_S)) is not None:
            out.append(line)
        assert self.process.stderr is not None
        return code, "".join(out), self.process.stderr.read()


@contextmanager
def serving(*args: str, env: dict[str, str] | None = None) -> Iterator[Served]:
    """``ncmeasure serve ARGS --port 0`` in its own process, and the URL it printed."""
    process = subprocess.Popen(
        [sys.executable, "-m", "ncmeasure", "serve", *args, "--port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "COLUMNS": "200", **(env or {})},
    )
    lines: queue.Queue[str | None] = queue.Queue()

    def read() -> None:
        assert process.stdout is not None
        for line in process.stdout:
            lines.put(line)
        lines.put(None)

    threading.Thread(target=read, daemon=True).start()
    try:
        line = lines.get(timeout=WAIT_S)
        assert line is not None, process.stderr.read() if process.stderr else ""
        yield Served(process, line, lines)
    finally:
        if process.poll() is None:
            process.kill()
        process.wait(timeout=WAIT_S)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_serve_answers_and_stops_on_a_signal(fleet: Fleet, sig: signal.Signals) -> None:
    with serving("--store", fleet.url) as served:
        url = served.url
        assert url.startswith("http://127.0.0.1:")
        machines = httpx.get(url + "api/v1/machines", timeout=WAIT_S).json()
        assert {m["serial"] for m in machines} == {s.info.serial for s in fleet.stored}
        assert "M-101" in httpx.get(url, timeout=WAIT_S).text
        code, out, err = served.stop(sig)
    assert code == 0, err
    assert "stopped" in out and "Traceback" not in err


def test_serve_takes_the_token_from_a_file_or_the_environment(fleet: Fleet, tmp_path: Path) -> None:
    token_file = tmp_path / "token"
    token_file.write_text(TOKEN + "\n", encoding="utf-8")
    for args, env in (
        (["--token-file", str(token_file)], None),
        ([], {"NCMEASURE_TOKEN": TOKEN}),
    ):
        with serving("--store", fleet.url, *args, env=env) as served:
            url = served.url
            assert httpx.get(url + "api/v1/machines", timeout=WAIT_S).status_code == 401
            allowed = httpx.get(
                url + "api/v1/machines",
                headers={"Authorization": f"Bearer {TOKEN}"},
                timeout=WAIT_S,
            )
            assert allowed.status_code == 200
            assert "token required" in served.first
            code, out, _ = served.stop()
        assert code == 0 and "stopped" in out


def _one_error_line(args: list[str], env: dict[str, str] | None = None) -> str:
    result = runner.invoke(app, ["serve", *args], env=env)
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    assert "Traceback" not in result.output
    return lines[0]


def test_bad_serve_settings_are_one_line(fleet: Fleet, tmp_path: Path) -> None:
    empty = tmp_path / "empty-token"
    empty.write_text("\n", encoding="utf-8")
    short = tmp_path / "short-token"
    short.write_text("abc\n", encoding="utf-8")
    store = ["--store", fleet.url, "--port", "0"]
    assert "token" in _one_error_line([*store, "--host", "0.0.0.0"], {"NCMEASURE_TOKEN": ""})
    assert "token" in _one_error_line([*store, "--host", "0.0.0.0"])
    assert "empty" in _one_error_line([*store, "--token-file", str(empty)])
    assert "16" in _one_error_line([*store, "--token-file", str(short)])
    assert "no such file" in _one_error_line([*store, "--token-file", str(tmp_path / "nope")])
    nothing = tmp_path / "nothing.db"
    assert "no such file" in _one_error_line(["--store", str(nothing), "--port", "0"])
    assert not nothing.exists()  # serving never creates a store
