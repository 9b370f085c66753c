"""Publishing to MQTT against a real mosquitto: what a subscriber receives, and every failure.

A subscriber connects after the publisher has gone and receives the retained
messages: exactly the stored characteristics. A broker that is down, wrong
credentials, a bad URL: one line, the right exit code, nothing lost from the store.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from ncmeasure.analysis.analyze import write_results
from ncmeasure.analysis.results import Results
from ncmeasure.cli import app
from ncmeasure.errors import ConfigError
from ncmeasure.publish.mqtt import PASSWORD_ENV, MqttTarget, topic_level
from ncmeasure.store import open_store
from tests.publish.broker import Broker, free_port

runner = CliRunner()
WAIT_S = 60.0  # a loaded computer may be slow; a correct run takes well under a second


def run(*args: str | Path, env: dict[str, str] | None = None) -> tuple[int, str, str]:
    result = runner.invoke(app, [str(a) for a in args], env=env)
    return result.exit_code, result.stdout, result.stderr


def receive(
    broker: Broker,
    count: int,
    topic: str = "ncmeasure/#",
    user: tuple[str, str] | None = None,
) -> dict[str, dict[str, Any]]:
    """The retained messages under ``topic``: topic -> decoded JSON (waits for ``count``)."""
    import paho.mqtt.client as mqtt

    got: dict[str, dict[str, Any]] = {}
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, protocol=mqtt.MQTTv311)
    client.on_message = lambda c, u, m: got.__setitem__(
        m.topic, {"retain": m.retain, "qos": m.qos, **json.loads(m.payload)}
    )
    client.on_connect = lambda c, u, f, rc, p: c.subscribe(topic, qos=1)
    if user is not None:
        client.username_pw_set(*user)
    if broker.ca_file is not None:
        client.tls_set(ca_certs=str(broker.ca_file))
    client.connect("127.0.0.1", broker.port)
    deadline = time.monotonic() + WAIT_S
    while len(got) < count and time.monotonic() < deadline:
        client.loop(timeout=0.1)
    client.disconnect()
    assert len(got) >= count, got
    return got


def stored_axes(url: str, serial: str) -> dict[str, Any]:
    with open_store(url) as store:
        _, measurements = store.machine(serial)
        return {
            axis: store.trend(serial, axis)
            for axis in sorted(store.results(measurements[-1].id).axes)
        }


def test_urls_are_read_and_bad_ones_refused(tmp_path: Path) -> None:
    target = MqttTarget.from_url("mqtt://127.0.0.1", env={})
    assert (target.host, target.port, target.prefix, target.tls) == (
        "127.0.0.1",
        1883,
        "ncmeasure",
        False,
    )
    target = MqttTarget.from_url(
        "mqtts://line3@broker:9883/plant/mqtt?site=hall-2&client_id=ncm", env={PASSWORD_ENV: "pw"}
    )
    assert (target.username, target.password, target.port, target.prefix) == (
        "line3",
        "pw",
        9883,
        "plant/mqtt",
    )
    assert target.where == "mqtts://line3@broker:9883" and target.site == "hall-2"
    assert topic_level("A/B+#%") == "A%2FB%2B%23%25"
    for url, words in (
        ("http://broker", "expected mqtt://"),
        ("mqtt://u:secret@broker", "set $NCMEASURE_MQTT_PASSWORD"),
        ("mqtt://broker:99999", "not a broker URL"),
        ("mqtt://broker?colour=red", "unknown parameter 'colour'"),
        ("mqtt://broker?topic={site}/x", "must hold {serial} and {axis}"),
        ("mqtt://broker/a/+", "wildcard"),
        ("mqtt://broker?ca=/x.pem", "ca= is for TLS"),
        (f"mqtts://broker?ca={tmp_path / 'none.pem'}", "does not exist"),
    ):
        with pytest.raises(ConfigError, match=None) as caught:
            MqttTarget.from_url(url, env={})
        assert words in caught.value.message, (url, caught.value.message)
    with pytest.raises(ConfigError, match="names no user"):
        MqttTarget.from_url("mqtt://broker", env={PASSWORD_ENV: "pw"})


def test_store_add_publishes_what_was_stored(
    tmp_path: Path, broker: Broker, make_results: Callable[..., Results]
) -> None:
    url = f"sqlite:///{tmp_path / 'fleet.db'}"
    publish = f"mqtt://127.0.0.1:{broker.port}/t1"
    files = [
        write_results(make_results(when, factor), tmp_path / f"{name}.json")
        for name, when, factor in (
            ("delivery", "2026-01-10T08:00:00+00:00", 1.0),
            ("service", "2029-01-10T08:00:00+00:00", 0.75),
        )
    ]
    code, out, err = run("store", "add", files[0], "--serial", "M 17#b", "--label", "delivery",
                         "--site", "plant/2", "--store", url, "--publish", publish)  # fmt: skip
    assert code == 0, err
    code, out, err = run("store", "add", files[1], "--serial", "M 17#b", "--label", "service",
                         "--store", url, "--publish", publish)  # fmt: skip
    assert code == 0, err
    assert "published 2 axis summaries to mqtt://127.0.0.1" in out
    stored = stored_axes(url, "M 17#b")
    got = receive(broker, len(stored), "t1/#")
    assert set(got) == {f"t1/plant%2F2/M 17%23b/{axis}/fingerprint" for axis in stored}
    for axis, trend in stored.items():
        message = got[f"t1/plant%2F2/M 17%23b/{axis}/fingerprint"]
        base, latest = trend[0], trend[-1]
        assert message["retain"] and message["qos"] == 1
        assert message["schema"] == "ncmeasure-fingerprint/1"
        assert (message["serial"], message["axis"], message["site"]) == ("M 17#b", axis, "plant/2")
        assert message["measurement_id"] == latest.measurement_id == 2
        assert message["measured_utc"] == latest.measured_utc and message["label"] == "service"
        assert message["baseline_id"] == base.measurement_id == 1
        assert message["unit"] == latest.unit and message["verdict"] == latest.verdict
        assert message["coulomb"] == latest.coulomb
        assert message["viscous_per_m_min"] == latest.viscous_per_m_min
        assert message["spread_percent"] == latest.spread_percent
        assert latest.coulomb is not None and base.coulomb is not None
        change = (latest.coulomb - base.coulomb) / abs(base.coulomb) * 100
        assert message["coulomb_change_percent"] == pytest.approx(change)
        assert message["coulomb_change_percent"] == pytest.approx(-25.0, abs=0.5)
        # −25 %: beyond the 20 % warning limit, within the 40 % critical one
        assert message["change_status"] == "warning" and message["status"] in (
            "warning",
            "critical",
        )
        expected = "FAILURE" if latest.verdict == "fault" else "MAINTENANCE_REQUIRED"
        assert (message["health"], message["health_code"]) == (
            expected,
            {"FAILURE": 1, "MAINTENANCE_REQUIRED": 4}[expected],
        )


def test_a_broker_that_is_down_loses_nothing(
    tmp_path: Path, store_with_machine: str, make_results: Callable[..., Results]
) -> None:
    results = write_results(make_results("2030-01-10T08:00:00+00:00", 0.9), tmp_path / "r.json")
    down = f"mqtt://127.0.0.1:{free_port()}"
    code, out, err = run("store", "add", results, "--serial", "M17", "--store", store_with_machine,
                         "--publish", down)  # fmt: skip
    assert code == 4, (out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: measurement 3 of M17 is stored"), err
    assert "cannot reach the broker" in lines[0] and "Traceback" not in out + err
    with open_store(store_with_machine) as store:
        assert [m.id for m in store.machine("M17")[1]] == [1, 2, 3]
    code, out, err = run("publish", "mqtt", down, "--store", store_with_machine)
    assert code == 4 and len(err.strip().splitlines()) == 1 and "cannot reach" in err


def test_bad_input_stores_nothing(
    tmp_path: Path, store_with_machine: str, make_results: Callable[..., Results]
) -> None:
    results = write_results(make_results("2030-01-10T08:00:00+00:00"), tmp_path / "r.json")
    for url in ("mqtt://u:pw@127.0.0.1", "tcp://127.0.0.1"):
        code, _, err = run("store", "add", results, "--serial", "M17", "--store",
                           store_with_machine, "--publish", url)  # fmt: skip
        assert code == 2 and len(err.strip().splitlines()) == 1, err
    with open_store(store_with_machine) as store:
        assert len(store.machine("M17")[1]) == 2
    code, _, err = run(
        "publish", "mqtt", "mqtt://127.0.0.1:1", "--serial", "M99", "--store", store_with_machine
    )
    assert code == 2 and "no measurement of 'M99'" in err


def test_credentials_and_tls(secure_broker: Broker, store_with_machine: str) -> None:
    url = f"mqtts://line3@127.0.0.1:{secure_broker.port}?ca={secure_broker.ca_file}&site=hall"
    code, out, err = run("publish", "mqtt", url, "--store", store_with_machine,
                         env={PASSWORD_ENV: "wrong"})  # fmt: skip
    assert code == 4, (out, err)
    assert len(err.strip().splitlines()) == 1 and "refused the connection" in err, err
    plain = f"mqtt://line3@127.0.0.1:{secure_broker.port}"
    code, out, err = run(
        "publish", "mqtt", plain, "--store", store_with_machine, env={PASSWORD_ENV: "s3cret-pw"}
    )
    assert code == 4 and len(err.strip().splitlines()) == 1, (out, err)
    code, out, err = run("publish", "mqtt", url, "--store", store_with_machine,
                         env={PASSWORD_ENV: "s3cret-pw"})  # fmt: skip
    assert code == 0, err
    got = receive(secure_broker, 2, user=("line3", "s3cret-pw"))
    # the site stored with the machine wins over ?site=
    assert all(topic.startswith("ncmeasure/plant-2/M17/") for topic in got), got


def test_analyze_publishes_after_storing(tmp_path: Path, broker: Broker) -> None:
    from ncmeasure.sim.synthetic import SyntheticAxis, geometric_velocities, synthetic_recording

    spec = SyntheticAxis(
        positions_mm=(50.0, 375.0, 700.0),
        coulomb=(2.0, 2.0, 2.0),
        velocities_mm_min=geometric_velocities(10.0, 15000.0, 8),
    )
    folder = tmp_path / "run1"
    _, schedule = synthetic_recording(folder, [spec], seed=1)
    assert schedule is not None
    schedule_file = tmp_path / "schedule.json"
    schedule_file.write_text(schedule.model_dump_json())
    store = tmp_path / "fleet.db"
    publish = f"mqtt://127.0.0.1:{broker.port}/t2?site=hall-9"
    code, _, err = run("analyze", folder, "--schedule", schedule_file, "--publish", publish)
    assert code == 2 and "give --store and --serial" in err
    code, out, err = run("analyze", folder, "--schedule", schedule_file, "--store", store,
                         "--serial", "A1", "--publish", publish)  # fmt: skip
    assert code == 0, err
    assert "published 1 axis summaries" in out
    got = receive(broker, 1, "t2/#")
    ((topic, message),) = got.items()
    trend = stored_axes(f"sqlite:///{store}", "A1")
    ((axis, points),) = trend.items()
    assert topic == f"t2/hall-9/A1/{axis}/fingerprint"
    assert message["coulomb"] == points[-1].coulomb and message["measurement_id"] == 1
    assert message["baseline_id"] is None and message["coulomb_change_percent"] is None
