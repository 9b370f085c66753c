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

from ncmeasure.cli import app
from ncmeasure.errors import ConfigError
from ncmeasure.formats.results import Results, write_results
from ncmeasure.publish.mqtt import PASSWORD_ENV, MqttTarget, topic_level
from ncmeasure.store import open_store
from tests.publish.broker import Broker, free_port

runner = CliRunner()
WAIT_S = 60.0  # a loaded computer may be slow; a correct run takes well under a second


def run(*args: str | Path, env: dict[str, str] | None = None) -> tuple[int, str, str]:
    result = runner.invoke(app, [str(a) for a in args], env=env)
    return result.exit_code, result.stdout, result.stderr


def receive(
    broker: Broker, prefix: str = "ncmeasure", user: tuple[str, str] | None = None
) -> dict[str, dict[str, Any]]:
    """Every retained message under ``prefix/#``, exactly: topic -> decoded JSON.

    The broker sends the retained messages of a subscription before anything
    published after it; so the subscriber, subscribed to ``prefix/#`` and to a
    topic of its own under ``probe/``, publishes an end marker there once
    subscribed, and has them all, and nothing else, when the marker comes back.
    """
    import uuid

    import paho.mqtt.client as mqtt

    got: dict[str, dict[str, Any]] = {}
    marker = f"probe/{uuid.uuid4().hex}"
    ended: list[bool] = []

    def on_message(client: Any, userdata: Any, message: Any) -> None:
        if message.topic == marker:
            ended.append(True)
        else:
            got[message.topic] = {
                "retain": message.retain,
                "qos": message.qos,
                **json.loads(message.payload),
            }

    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, protocol=mqtt.MQTTv311)
    client.on_message = on_message
    client.on_connect = lambda c, u, f, rc, p: c.subscribe([(f"{prefix}/#", 1), (marker, 1)])
    client.on_subscribe = lambda c, u, mid, rc, p: c.publish(marker, b"", qos=1)
    if user is not None:
        client.username_pw_set(*user)
    if broker.ca_file is not None:
        client.tls_set(ca_certs=str(broker.ca_file))
    client.connect("127.0.0.1", broker.port)
    deadline = time.monotonic() + WAIT_S
    while not ended and time.monotonic() < deadline:
        client.loop(timeout=0.1)
    client.disconnect()
    assert ended, f"the end marker did not come back; got {sorted(got)}"
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
    assert target.protocol == "5"
    assert MqttTarget.from_url("mqtt://b?protocol=3.1.1", env={}).protocol == "3.1.1"
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
        ("mqtt://broker?protocol=4", "protocol='4': 5 or 3.1.1"),
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
            ("service", "2029-01-10T08:00:00+00:00", 0.85),
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
    got = receive(broker, "t1")
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
        assert message["coulomb_change_percent"] == pytest.approx(-15.0, abs=0.5)
        # −15 %: beyond the 10 % warning limit, within the 25 % critical one; alike along
        # the travel, so X's fault from its pattern (its fingerprint, unchanged) does not count
        assert message["change_status"] == "warning" and message["status"] == "warning"
        assert (message["health"], message["health_code"]) == ("MAINTENANCE_REQUIRED", 4)


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
    got = receive(secure_broker, user=("line3", "s3cret-pw"))
    assert len(got) == 2
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
    down = f"mqtt://127.0.0.1:{free_port()}"
    code, out, err = run("analyze", folder, "--schedule", schedule_file, "--store", store,
                         "--serial", "A1", "--publish", down)  # fmt: skip
    assert code == 4, (out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "measurement 1 of A1 is stored, but was not published" in lines[0]
    assert (tmp_path / "run1.results.json").is_file() and "Traceback" not in err
    code, out, err = run("publish", "mqtt", publish, "--store", store)  # later, as the line says
    assert code == 0, err
    ((topic, message),) = receive(broker, "t2").items()
    trend = stored_axes(f"sqlite:///{store}", "A1")
    ((axis, points),) = trend.items()
    assert topic == f"t2/hall-9/A1/{axis}/fingerprint"
    assert message["coulomb"] == points[-1].coulomb and message["measurement_id"] == 1
    assert message["baseline_id"] is None and message["coulomb_change_percent"] is None
    other = tmp_path / "other.db"  # a broker that is up: published right after storing
    publish = f"mqtt://127.0.0.1:{broker.port}/t2b?site=hall-9"
    code, out, err = run("analyze", folder, "--schedule", schedule_file, "--store", other,
                         "--serial", "A1", "--publish", publish)  # fmt: skip
    assert code == 0, err
    assert "stored as measurement 1 of A1" in out and "published 1 axis summaries" in out
    ((topic, message),) = receive(broker, "t2b").items()
    assert topic == f"t2b/hall-9/A1/{axis}/fingerprint" and message["measurement_id"] == 1
    assert message["coulomb"] == stored_axes(f"sqlite:///{other}", "A1")[axis][-1].coulomb


def test_publish_on_demand_sends_exactly_what_is_stored(
    broker: Broker, store_with_machine: str
) -> None:
    """Every axis of the store, nothing else; each message what the store and the
    analysis say of that measurement: its verdict, its figures, the dashboard's light."""
    from ncmeasure.store.overview import fleet_overview

    code, out, err = run(
        "publish", "mqtt", f"mqtt://127.0.0.1:{broker.port}/t3", "--store", store_with_machine
    )
    assert code == 0, err
    got = receive(broker, "t3")
    with open_store(store_with_machine) as store:
        overview = fleet_overview(store)
        (machine,) = overview.machines
        results = store.results(machine.latest_id)
    assert set(got) == {f"t3/plant-2/M17/{axis}/fingerprint" for axis in results.axes}
    assert out.strip() == f"published {len(got)} axis summaries to mqtt://127.0.0.1:{broker.port}"
    for axis, analysed in results.axes.items():
        message = got[f"t3/plant-2/M17/{axis}/fingerprint"]
        shown = machine.axes[axis]
        assert message["verdict"] == analysed.verdict.level == shown.verdict
        assert message["status"] == shown.status  # store report's and the dashboard's light
        assert message["measurement_id"] == machine.latest_id
        assert message["coulomb"] == shown.latest["coulomb"]
        assert (message["warning_percent"], message["critical_percent"]) == (10.0, 25.0)


@pytest.mark.parametrize(
    ("limits", "change_status"),
    [
        (("--warning", "10", "--critical", "20"), "critical"),
        (("--warning", "30", "--critical", "40"), "ok"),
    ],
)
def test_the_limits_judge_the_published_change(
    broker: Broker, store_with_machine: str, limits: tuple[str, ...], change_status: str
) -> None:
    """The same limits as `store report`: −24 % is critical beyond 20 %, ok within 30 %."""
    prefix = f"limits-{change_status}"
    url = f"mqtt://127.0.0.1:{broker.port}/{prefix}"
    code, _, err = run("publish", "mqtt", url, "--store", store_with_machine, *limits)
    assert code == 0, err
    got = receive(broker, prefix)
    assert len(got) == 2
    for message in got.values():
        assert message["coulomb_change_percent"] == pytest.approx(-24.0, abs=0.5)
        assert message["change_status"] == change_status
        # X's fault from its pattern is unchanged since delivery: no assembly fault found
        # now (no FAILURE), a warning to confirm; the change decides beyond that
        if change_status == "critical":
            assert (message["health"], message["status"]) == ("OFF_SPEC", "critical")
        elif message["axis"] == "X":
            assert (message["health"], message["status"]) == ("MAINTENANCE_REQUIRED", "warning")
        else:
            assert (message["health"], message["status"]) == ("NORMAL", "ok")
    code, _, err = run("publish", "mqtt", url, "--store", store_with_machine,
                       "--warning", "50", "--critical", "40")  # fmt: skip
    assert code == 2 and len(err.strip().splitlines()) == 1, err


def test_wrong_credentials_keep_the_stored_result(
    tmp_path: Path,
    password_broker: Broker,
    store_with_machine: str,
    make_results: Callable[..., Results],
) -> None:
    results = write_results(make_results("2030-01-10T08:00:00+00:00", 0.9), tmp_path / "r.json")
    url = f"mqtt://line3@127.0.0.1:{password_broker.port}/t4"
    for password in ("wrong", None):  # a wrong password, and none at all
        env = {PASSWORD_ENV: password} if password else {}
        code, out, err = run("store", "add", results, "--serial", "M17",
                             "--store", store_with_machine, "--publish", url, env=env)  # fmt: skip
        assert code == 4, (out, err)
        lines = err.strip().splitlines()
        assert len(lines) == 1 and "is stored, but was not published" in lines[0], err
        assert "refused the connection" in lines[0] and "NCMEASURE_MQTT_PASSWORD" in lines[0]
        assert "Traceback" not in out + err
    with open_store(store_with_machine) as store:
        assert [m.id for m in store.machine("M17")[1]] == [1, 2, 3]  # stored once, kept
    code, out, err = run("publish", "mqtt", url, "--store", store_with_machine,
                         env={PASSWORD_ENV: "s3cret-pw"})  # fmt: skip
    assert code == 0, err
    got = receive(password_broker, "t4", user=("line3", "s3cret-pw"))
    assert {m["measurement_id"] for m in got.values()} == {3}


def test_a_message_the_broker_refuses_is_an_error(
    read_only_broker: Broker, store_with_machine: str
) -> None:
    """MQTT 5 reports a message the access rules refuse; MQTT 3.1.1 cannot."""
    url = f"mqtt://line3@127.0.0.1:{read_only_broker.port}"
    env = {PASSWORD_ENV: "s3cret-pw"}
    code, out, err = run("publish", "mqtt", url, "--store", store_with_machine, env=env)
    assert code == 4, (out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "the broker refused 2 of 2 message(s) (Not authorized" in lines[0]
    assert "access rules" in lines[0] and "published" not in out
    assert receive(read_only_broker, "ncmeasure", user=("line3", "s3cret-pw")) == {}
    code, out, err = run("publish", "mqtt", url + "?protocol=3.1.1", "--store",
                         store_with_machine, env=env)  # fmt: skip
    assert code == 0 and "published 2" in out, err  # the limit docs/shop-floor.md states
    assert receive(read_only_broker, "ncmeasure", user=("line3", "s3cret-pw")) == {}


def test_tls_mistakes_are_one_line(
    broker: Broker, secure_broker: Broker, store_with_machine: str
) -> None:
    env = {PASSWORD_ENV: "s3cret-pw"}
    for url, words in (
        (f"mqtts://line3@127.0.0.1:{secure_broker.port}", "trust its CA with ?ca=FILE"),
        (f"mqtts://127.0.0.1:{broker.port}?ca={secure_broker.ca_file}", "wants mqtt://"),
    ):
        code, out, err = run(
            "publish", "mqtt", url, "--store", store_with_machine,
            env=env if "line3" in url else {},
        )  # fmt: skip
        lines = err.strip().splitlines()
        assert code == 4 and len(lines) == 1 and "Traceback" not in err, (out, err)
        assert words in lines[0], lines[0]


def test_a_broker_that_never_answers_times_out(store_with_machine: str) -> None:
    import socket

    from ncmeasure.errors import PublishError
    from ncmeasure.publish import axis_summaries
    from ncmeasure.publish.mqtt import publish_summaries
    from ncmeasure.store.overview import fleet_overview

    with open_store(store_with_machine) as store:
        summaries = axis_summaries(fleet_overview(store))
    with socket.socket() as silent:  # accepts (the kernel's backlog), never answers
        silent.bind(("127.0.0.1", 0))
        silent.listen()
        target = MqttTarget(host="127.0.0.1", port=silent.getsockname()[1], timeout_s=0.5)
        with pytest.raises(PublishError) as caught:
            publish_summaries(target, summaries)
    assert "no answer from the broker in 0.5 s (connecting)" in caught.value.message


def test_the_topic_template(broker: Broker, store_with_machine: str) -> None:
    url = f"mqtt://127.0.0.1:{broker.port}/t5?topic={{machine_type}}/{{serial}}/{{axis}}"
    code, _, err = run("publish", "mqtt", url, "--store", store_with_machine, "--serial", "M17")
    assert code == 0, err
    got = receive(broker, "t5")
    ((topic, message), *_) = sorted(got.items())
    assert topic == f"t5/{topic_level(message['machine_type'])}/M17/X"
    assert len(got) == 2
