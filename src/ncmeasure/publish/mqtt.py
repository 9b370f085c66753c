"""Publish the axis summaries to an MQTT broker: retained JSON, QoS 1, one topic per axis.

The broker is named by a URL, the form ``--store`` has taught::

    mqtt://[USER@]HOST[:PORT][/PREFIX][?site=SITE&client_id=ID&topic=TEMPLATE&protocol=5]
    mqtts://...                 TLS (port 8883), the system's CAs or ?ca=FILE

The password never comes from the command line (other users can read it
there): it is read from ``$NCMEASURE_MQTT_PASSWORD``. Each axis goes to
``PREFIX/SITE/SERIAL/AXIS/fingerprint`` (prefix ``ncmeasure``; the site is the
machine's site in the store, else ``?site=``, else ``unknown``), retained, so
a subscriber that connects later gets the latest fingerprint at once.

MQTT 5 by default: the broker acknowledges each message with a reason code,
so a message its access rules refuse (PUBACK "Not authorized") is an error
naming the topic, not a silent loss. ``?protocol=3.1.1`` speaks to a broker
without MQTT 5; that protocol acknowledges refused messages like accepted ones.

paho-mqtt 2.x with its version 2 callbacks (CallbackAPIVersion.VERSION2,
https://eclipse.dev/paho/files/paho.mqtt.python/html/migrations.html); the
client's network loop is run here, in bounded steps, so that every wait has
a time-out and no thread is left behind. Every failure (no broker, refused
credentials, TLS, a message refused or not acknowledged) is one :class:`PublishError`.
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
_QUERY = {"site", "client_id", "topic", "ca", "protocol"}
PROTOCOLS = ("5", "3.1.1")
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
    protocol: str = "5"
    """MQTT version: ``5`` (refused messages are reported) or ``3.1.1``."""
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
        protocol = query.get("protocol", "5")
        if protocol not in PROTOCOLS:
            raise ConfigError(f"{where}: protocol={protocol!r}: 5 or 3.1.1")
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
            protocol=protocol,
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
        self.rejected: dict[int, str] = {}
        """Message id -> the broker's reason for refusing it (MQTT 5 PUBACK)."""

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

    def on_publish(self, client: Any, userdata: Any, mid: int, reason: Any, props: Any) -> None:
        if reason.is_failure:
            self.rejected[mid] = str(reason)


def publish_summaries(target: MqttTarget, summaries: Sequence[AxisSummary]) -> Published:
    """Publish one retained QoS 1 message per axis summary and wait for the broker's acks.

    Raises:
        DependencyError: paho-mqtt is not installed.
        PublishError: The broker cannot be reached, refuses the client (credentials,
            not authorised), TLS fails, refuses a message (MQTT 5: its access rules),
            or does not acknowledge one in time.
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
        protocol=mqtt.MQTTv5 if target.protocol == "5" else mqtt.MQTTv311,
    )
    client.on_connect = session.on_connect
    client.on_disconnect = session.on_disconnect
    client.on_publish = session.on_publish
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
            if "VERIFY" in str(exc.reason):
                hint = " (trust its CA with ?ca=FILE)"
            elif isinstance(exc, ssl.SSLEOFError | ssl.SSLZeroReturnError):
                hint = "; a plain MQTT port wants mqtt://"
            else:
                hint = ""
            raise PublishError(f"{target.where}: TLS failed ({exc.reason or exc}){hint}") from exc
        except OSError as exc:
            hint = (
                "; a plain MQTT port wants mqtt://"
                if target.tls and isinstance(exc, ConnectionResetError)
                else ""
            )
            raise PublishError(
                f"{target.where}: cannot reach the broker ({exc.strerror or exc}){hint}"
            ) from exc
        while not session.connected:
            _step(client, session, target, deadline, "connecting")
        infos = [client.publish(topic, payload, qos=1, retain=True) for topic, payload in messages]
        while not all(info.is_published() for info in infos):
            _step(client, session, target, deadline, "waiting for the broker's acknowledgements")
        sent = [(info.mid, topic) for info, (topic, _) in zip(infos, messages, strict=True)]
        _rejected(session, target, sent)
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
        hint = (
            ""
            if target.tls or session.connected
            else "; a TLS port wants mqtts://"
            + ("; a broker without MQTT 5 ?protocol=3.1.1" if target.protocol == "5" else "")
        )
        raise PublishError(
            f"{target.where}: the broker closed the connection ({reason}; {doing}{hint})"
        )


def _rejected(session: _Session, target: MqttTarget, sent: list[tuple[int, str]]) -> None:
    """A :class:`PublishError` if the broker refused any message (MQTT 5 PUBACK)."""
    refused = [(topic, session.rejected[mid]) for mid, topic in sent if mid in session.rejected]
    if not refused:
        return
    topic, reason = refused[0]
    raise PublishError(
        f"{target.where}: the broker refused {len(refused)} of {len(sent)} message(s) "
        f"({reason}: {topic}{', ...' if len(refused) > 1 else ''}); check its access rules "
        "(ACL) for this user and topic"
    )


def _refused(session: _Session, target: MqttTarget) -> None:
    if session.refused is None:
        return
    reason = session.refused.lower()
    hint = (
        f"; check the user name and ${PASSWORD_ENV}"
        if "authori" in reason or "password" in reason
        else "; a broker without MQTT 5 wants ?protocol=3.1.1"
        if "protocol" in reason
        else ""
    )
    raise PublishError(
        f"{target.where}: the broker refused the connection ({session.refused}{hint})"
    )
