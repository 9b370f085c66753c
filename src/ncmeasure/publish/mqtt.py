"""Publish the axis summaries to an MQTT broker: retained JSON, QoS 1, one topic per axis.

The broker is named by a URL, the form ``--store`` has taught::

    mqtt://[USER@]HOST[:PORT][/PREFIX][?site=SITE&client_id=ID&topic=TEMPLATE]
    mqtts://...                 TLS (port 8883), the system's CAs or ?ca=FILE

The password never comes from the command line (other users can read it
there): it is read from ``$NCMEASURE_MQTT_PASSWORD``. Each axis goes to
``PREFIX/SITE/SERIAL/AXIS/fingerprint`` (prefix ``ncmeasure``; the site is the
machine's site in the store, else ``?site=``, else ``unknown``), retained, so
a subscriber that connects later gets the latest fingerprint at once.

paho-mqtt 2.x with its version 2 callbacks (CallbackAPIVersion.VERSION2,
https://eclipse.dev/paho/files/paho.mqtt.python/html/migrations.html); the
client's network loop is run here, in bounded steps, so that every wait has
a time-out and no thread is left behind. Every failure (no broker, refused
credentials, TLS, a message not acknowledged) is one :class:`PublishError`.
"""

from __future__ import annotations

import json
import logging
import os
import ssl
import string
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import parse_qsl, unquote, urlsplit

from ncmeasure.errors import ConfigError, DependencyError, PublishError
from ncmeasure.publish.summary import AxisSummary

__all__ = [
    "DEFAULT_PREFIX",
    "DEFAULT_TOPIC",
    "PASSWORD_ENV",
    "MqttTarget",
    "Published",
    "paho",
    "publish_summaries",
    "topic_level",
]

_log = logging.getLogger(__name__)

PASSWORD_ENV = "NCMEASURE_MQTT_PASSWORD"
DEFAULT_PREFIX = "ncmeasure"
DEFAULT_TOPIC = "{site}/{serial}/{axis}/fingerprint"
"""Below the prefix; ``?topic=`` replaces it (fields: site, serial, axis, machine_type)."""
UNKNOWN_SITE = "unknown"
_FIELDS = {"site", "serial", "axis", "machine_type"}
_QUERY = {"site", "client_id", "topic", "ca"}
_DEFAULT_PORTS = {"mqtt": 1883, "mqtts": 8883}
_ESCAPED = {"%": "%25", "/": "%2F", "+": "%2B", "#": "%23"}


def topic_level(text: str) -> str:
    """``text`` as one topic level: ``% / + #`` and control characters percent-encoded.

    A serial such as ``A/B#2`` would otherwise open levels or be a wildcard.
    """
    out = []
    for char in text:
        if char in _ESCAPED:
            out.append(_ESCAPED[char])
        elif ord(char) < 0x20 or ord(char) == 0x7F:
            out.append(f"%{ord(char):02X}")
        else:
            out.append(char)
    return "".join(out) or "%00"


@dataclass(frozen=True)
class MqttTarget:
    """Where and how to publish (see the module docstring for the URL)."""

    host: str
    port: int = 1883
    tls: bool = False
    ca_file: Path | None = None
    username: str | None = None
    password: str | None = None
    prefix: str = DEFAULT_PREFIX
    topic: str = DEFAULT_TOPIC
    site: str | None = None
    client_id: str = ""
    timeout_s: float = 10.0

    @property
    def where(self) -> str:
        """The broker's URL without the password (for messages)."""
        user = f"{self.username}@" if self.username else ""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{'mqtts' if self.tls else 'mqtt'}://{user}{host}:{self.port}"

    @classmethod
    def from_url(cls, url: str, env: Mapping[str, str] | None = None) -> MqttTarget:
        """The target named by ``url``; the password from ``$NCMEASURE_MQTT_PASSWORD``.

        Raises:
            ConfigError: Not an MQTT URL, a password in it, an unknown parameter,
                a topic template that is not one, a missing CA file.
        """
        env = os.environ if env is None else env
        where = f"--publish {url}"
        try:
            parts = urlsplit(url)
            port = parts.port
        except ValueError as exc:
            raise ConfigError(f"{where}: not a broker URL ({exc})") from exc
        if parts.scheme not in _DEFAULT_PORTS or not parts.hostname:
            raise ConfigError(
                f"{where}: expected mqtt://[USER@]HOST[:PORT][/PREFIX] or mqtts://... "
                "(e.g. mqtt://127.0.0.1:1883)"
            )
        if parts.password is not None:
            raise ConfigError(
                f"{where}: a password in the URL is visible to every user of this computer; "
                f"set ${PASSWORD_ENV} instead"
            )
        if parts.fragment:
            raise ConfigError(f"{where}: a URL fragment (#...) means nothing here")
        query: dict[str, str] = {}
        for key, value in parse_qsl(parts.query, keep_blank_values=True):
            if key not in _QUERY:
                raise ConfigError(
                    f"{where}: unknown parameter {key!r} (known: {', '.join(sorted(_QUERY))})"
                )
            query[key] = value
        prefix = unquote(parts.path).strip("/") or DEFAULT_PREFIX
        if any(c in prefix for c in "+#\0"):
            raise ConfigError(f"{where}: the topic prefix {prefix!r} holds a wildcard (+ or #)")
        topic = query.get("topic", DEFAULT_TOPIC).strip("/")
        _check_template(topic, where)
        ca = Path(query["ca"]) if query.get("ca") else None
        if ca is not None and parts.scheme != "mqtts":
            raise ConfigError(f"{where}: ca= is for TLS; use mqtts://")
        if ca is not None and not ca.is_file():
            raise ConfigError(f"{where}: the CA file {ca} does not exist")
        username = unquote(parts.username) if parts.username else None
        password = env.get(PASSWORD_ENV)
        if password is not None and username is None:
            raise ConfigError(
                f"{where}: ${PASSWORD_ENV} is set but the URL names no user (mqtt://USER@HOST)"
            )
        return cls(
            host=parts.hostname,
            port=port or _DEFAULT_PORTS[parts.scheme],
            tls=parts.scheme == "mqtts",
            ca_file=ca,
            username=username,
            password=password,
            prefix=prefix,
            topic=topic,
            site=query.get("site") or None,
            client_id=query.get("client_id", ""),
        )

    def topic_of(self, summary: AxisSummary) -> str:
        """The topic of one axis summary."""
        machine = summary.machine
        site = machine.site or self.site or UNKNOWN_SITE
        levels = {
            "site": topic_level(site),
            "serial": topic_level(machine.serial),
            "axis": topic_level(summary.axis.axis),
            "machine_type": topic_level(machine.machine_type),
        }
        return f"{self.prefix}/{self.topic.format(**levels)}"


def _check_template(topic: str, where: str) -> None:
    try:
        names = {name for _, name, _, _ in string.Formatter().parse(topic) if name is not None}
    except ValueError as exc:
        raise ConfigError(f"{where}: topic={topic!r} is not a template ({exc})") from exc
    unknown = names - _FIELDS
    if unknown or not {"serial", "axis"} <= names:
        raise ConfigError(
            f"{where}: topic={topic!r} must hold {{serial}} and {{axis}} and may hold "
            f"{{site}} and {{machine_type}}"
            + (f" (not {', '.join(sorted(unknown))})" if unknown else "")
        )
    literal = string.Formatter().parse(topic)
    if any(c in text for text, _, _, _ in literal for c in "+#\0"):
        raise ConfigError(f"{where}: topic={topic!r} holds a wildcard (+ or #)")


@dataclass(frozen=True)
class Published:
    """What :func:`publish_summaries` sent."""

    target: str
    topics: list[str]


def paho() -> Any:
    """paho.mqtt.client, or a :class:`DependencyError` naming the extra."""
    try:
        import paho.mqtt.client as mqtt
    except ImportError as exc:
        raise DependencyError(
            "publishing to MQTT needs the package 'paho-mqtt', which is missing "
            "(pip install 'ncmeasure[mqtt]')"
        ) from exc
    return mqtt


class _Session:
    """One connection: what the callbacks learnt, read by the loop below."""

    def __init__(self) -> None:
        self.connected = False
        self.refused: str | None = None
        self.lost: str | None = None

    def on_connect(self, client: Any, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
        if reason.is_failure:
            self.refused = str(reason)
        else:
            self.connected = True

    def on_disconnect(
        self, client: Any, userdata: Any, flags: Any, reason: Any, props: Any
    ) -> None:
        if self.refused is None:
            self.lost = str(reason)
        self.connected = False


def publish_summaries(target: MqttTarget, summaries: Sequence[AxisSummary]) -> Published:
    """Publish one retained QoS 1 message per axis summary and wait for the broker's acks.

    Raises:
        DependencyError: paho-mqtt is not installed.
        PublishError: The broker cannot be reached, refuses the client (credentials,
            not authorised), TLS fails, or a message is not acknowledged in time.
    """
    mqtt = paho()
    messages = [
        (target.topic_of(s), json.dumps(s.message(), allow_nan=False, separators=(",", ":")))
        for s in summaries
    ]
    session = _Session()
    client = mqtt.Client(
        callback_api_version=mqtt.CallbackAPIVersion.VERSION2,
        client_id=target.client_id,
        protocol=mqtt.MQTTv311,
    )
    client.on_connect = session.on_connect
    client.on_disconnect = session.on_disconnect
    client.connect_timeout = target.timeout_s
    if target.username is not None:
        client.username_pw_set(target.username, target.password)
    if target.tls:
        try:
            client.tls_set(ca_certs=str(target.ca_file) if target.ca_file else None)
        except (ssl.SSLError, OSError) as exc:
            raise PublishError(f"{target.where}: TLS cannot be set up ({exc})") from exc
    deadline = time.monotonic() + target.timeout_s
    try:
        try:
            client.connect(target.host, target.port, keepalive=max(10, int(target.timeout_s * 2)))
        except ssl.SSLError as exc:
            hint = " (trust its CA with ?ca=FILE)" if "VERIFY" in str(exc.reason) else ""
            raise PublishError(f"{target.where}: TLS failed ({exc.reason or exc}){hint}") from exc
        except OSError as exc:
            raise PublishError(
                f"{target.where}: cannot reach the broker ({exc.strerror or exc})"
            ) from exc
        while not session.connected:
            _step(client, session, target, deadline, "connecting")
        infos = [client.publish(topic, payload, qos=1, retain=True) for topic, payload in messages]
        while not all(info.is_published() for info in infos):
            _step(client, session, target, deadline, "waiting for the broker's acknowledgements")
    finally:
        client.disconnect()  # harmless when not connected
        for _ in range(20):  # let DISCONNECT leave; the loop fails once the socket is closed
            if client.loop(timeout=0.05) != mqtt.MQTT_ERR_SUCCESS:
                break
    _log.debug("published %d message(s) to %s", len(messages), target.where)
    return Published(target=target.where, topics=[topic for topic, _ in messages])


def _step(client: Any, session: _Session, target: MqttTarget, deadline: float, doing: str) -> None:
    """One bounded turn of the network loop; an error once the broker refused or went."""
    _refused(session, target)
    if time.monotonic() > deadline:
        raise PublishError(
            f"{target.where}: no answer from the broker in {target.timeout_s:g} s ({doing})"
        )
    rc = client.loop(timeout=0.1)
    _refused(session, target)
    if rc != 0 or session.lost is not None:
        reason = session.lost or str(rc)
        hint = "" if target.tls or session.connected else "; a TLS port wants mqtts://"
        raise PublishError(
            f"{target.where}: the broker closed the connection ({reason}; {doing}{hint})"
        )


def _refused(session: _Session, target: MqttTarget) -> None:
    if session.refused is None:
        return
    hint = (
        f"; check the user name and ${PASSWORD_ENV}"
        if "authori" in session.refused.lower() or "password" in session.refused.lower()
        else ""
    )
    raise PublishError(
        f"{target.where}: the broker refused the connection ({session.refused}{hint})"
    )
