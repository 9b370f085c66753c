"""The help of the shop-floor commands teaches: what they do, how to log in, an example."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from ncmeasure.cli import app


def help_of(*command: str) -> str:
    result = CliRunner().invoke(app, [*command, "--help"], env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.stderr
    return result.stdout


@pytest.mark.parametrize(
    ("command", "words"),
    [
        (("publish",), ("mqtt", "opcua", "docs/shop-floor.md")),
        (
            ("publish", "mqtt"),
            ("{URL}", "$NCMEASURE_MQTT_PASSWORD", "mqtts://", "?ca=FILE", "protocol=5",
             "--warning", "--critical", "--serial SERIAL", "exit 4", "Example:"),
        ),
        (
            ("publish", "opcua"),
            ("loopback", "$NCMEASURE_OPCUA_PASSWORD", "--certificate", "--trusted-clients FOLDER",
             "Basic256Sha256", "--refresh-s", "--warning", "Nobody can write", "Example:"),
        ),
        (("store", "add"), ("{RESULTS_FILE}", "--publish URL", "$NCMEASURE_MQTT_PASSWORD")),
        (("analyze",), ("--publish URL",)),
        (("compensation",), ("twincat", "linuxcnc", "cia402", "apply-compensation", "exit 2")),
        (
            ("apply-compensation",),
            ("{FILE}", "--machine", "--yes", "0x60B2", "read back", "nothing is sent",
             "Exit code", "Example:"),
        ),
    ],
)  # fmt: skip
def test_help_teaches(command: tuple[str, ...], words: tuple[str, ...]) -> None:
    text = " ".join(help_of(*command).split())
    for word in words:
        assert word in text, (command, word)
