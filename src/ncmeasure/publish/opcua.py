"""The fleet store as an OPC UA server (asyncua): Machines → Machine → Axes → Axis.

The address space (docs/shop-floor.md draws it with every variable)::

    Objects
    └── Machines                          folder            ns=urn:ncmeasure:fleet
        └── <serial>                      object (BrowseName: the serial)
            ├── MachineType, Site, Measurements, DeviceHealth (worst axis)
            └── Axes                      folder
                └── <axis>                object (X, Y, Z, ...)
                    ├── Coulomb, Viscous, Spread           EngineeringUnits
                    ├── CoulombChange, ViscousChange, SpreadChange
                    ├── Verdict, Status, DeviceHealth, MeasurementId, MeasuredTime

The values are those of the MQTT message (:mod:`ncmeasure.publish.summary`),
each characteristic with the measurement's time as its SourceTimestamp and its
unit as ``EngineeringUnits`` (EUInformation, UN/CEFACT codes where one exists:
OPC 10000-8, 5.6.3). ``DeviceHealth`` has the DI ``DeviceHealthEnumeration``
as its data type, declared here under the DI namespace URI with the DI
nodeset's id (``i=6244``) so that clients that know DI recognise it.

The server reads the store again every ``refresh_s`` and writes only what
changed, so a subscriber gets a data change when ``store add`` brings a new
measurement. Access: anonymous and read-only on a loopback address (the
default ``opc.tcp://127.0.0.1:4840``); any other address needs a user name
and password and a server certificate (Basic256Sha256, sign and encrypt, the
only endpoint then). With a folder of trusted client certificates
(``trusted_clients``) only clients whose application instance certificate, or
the CA that issued it, lies there may open a session (BadCertificateUntrusted
for the others). Nobody may write, add or delete nodes: the built-in admin is
switched off and every user is an ordinary one.
"""

from __future__ import annotations

import asyncio
import datetime as dt
import hmac
import logging
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from ncmeasure.errors import ConfigError, DependencyError, PublishError, StoreError
from ncmeasure.formats.comparison import Limits
from ncmeasure.hosts import is_loopback
from ncmeasure.publish.summary import DEVICE_HEALTH, AxisSummary, device_health, worst_health
from ncmeasure.store import open_store
from ncmeasure.store.overview import FleetOverview, MachineOverview, fleet_overview

__all__ = [
    "DEFAULT_ENDPOINT",
    "DI_NAMESPACE",
    "NAMESPACE",
    "PASSWORD_ENV",
    "OpcUaSettings",
    "TrustList",
    "engineering_units",
    "load_trusted_clients",
    "serve_opcua",
]

_log = logging.getLogger(__name__)

DEFAULT_ENDPOINT = "opc.tcp://127.0.0.1:4840"
NAMESPACE = "urn:ncmeasure:fleet"
"""The namespace of the machines, axes and their variables."""
DI_NAMESPACE = "http://opcfoundation.org/UA/DI/"
DEVICE_HEALTH_TYPE_ID = 6244
"""DeviceHealthEnumeration's id in the DI nodeset (https://reference.opcfoundation.org/nodesets/11/17484)."""
PASSWORD_ENV = "NCMEASURE_OPCUA_PASSWORD"
CEFACT = "http://www.opcfoundation.org/UA/units/un/cefact"
"""EUInformation.namespaceUri of the UN/CEFACT units (OPC 10000-8, 5.6.3.4)."""

# UN/CEFACT Recommendation 20 common codes; unitId is the code's ASCII bytes as one
# integer (OPC 10000-8, 5.6.3.4: MMT -> 5066068). AMP and P1 as in node-opcua's
# standard units, NU (20053) as in Eclipse Milo's CefactEngineeringUnits.
_UNITS: dict[str, tuple[str, str]] = {
    "A": ("AMP", "ampere"),
    "Nm": ("NU", "newton metre"),
    "%": ("P1", "percent"),
}


def _unit_id(code: str) -> int:
    value = 0
    for char in code:
        value = (value << 8) | ord(char)
    return value


def engineering_units(unit: str) -> tuple[str, int, str, str]:
    """(namespaceUri, unitId, displayName, description) of a unit ncmeasure reports.

    A, Nm and % have UN/CEFACT codes; the others (``A/(m/min)``, percentage
    points ``pp``) have none: unitId -1, as OPC 10000-8 asks.
    """
    known = _UNITS.get(unit)
    if known is not None:
        code, name = known
        return CEFACT, _unit_id(code), unit, name
    names = {"pp": "percentage points of the spread"}
    return "", -1, unit, names.get(unit, unit)


@dataclass(frozen=True)
class OpcUaSettings:
    """How the server listens and whom it lets in."""

    endpoint: str = DEFAULT_ENDPOINT
    refresh_s: float = 10.0
    username: str | None = None
    password: str | None = None
    certificate: Path | None = None
    private_key: Path | None = None
    trusted_clients: Path | None = None
    """A folder of client certificates (or their CAs), PEM or DER: only those may connect."""

    @property
    def host_port(self) -> tuple[str, int]:
        """The address the endpoint names (checked by :meth:`checked`)."""
        parts = urlsplit(self.endpoint)
        assert parts.hostname is not None and parts.port is not None
        return parts.hostname, parts.port

    def checked(self) -> OpcUaSettings:
        """These settings if they are usable, else a :class:`ConfigError` saying why."""
        where = f"--endpoint {self.endpoint}"
        try:
            parts = urlsplit(self.endpoint)
            port = parts.port
        except ValueError as exc:
            raise ConfigError(f"{where}: not an endpoint URL ({exc})") from exc
        if parts.scheme != "opc.tcp" or not parts.hostname or not port:
            raise ConfigError(f"{where}: expected opc.tcp://HOST:PORT (e.g. {DEFAULT_ENDPOINT})")
        if not (0.1 <= self.refresh_s <= 86400) or not math.isfinite(self.refresh_s):
            raise ConfigError(f"--refresh-s {self.refresh_s:g}: between 0.1 and 86400 s")
        if (self.username is None) != (self.password is None):
            raise ConfigError(
                f"--user and ${PASSWORD_ENV} go together: give both or neither"
                if self.username is None or not self.password
                else "--user needs a password"
            )
        if self.password is not None and not self.password:
            raise ConfigError(f"${PASSWORD_ENV}: empty")
        if (self.certificate is None) != (self.private_key is None):
            raise ConfigError("--certificate and --private-key go together")
        for path in (self.certificate, self.private_key):
            if path is not None and not path.is_file():
                raise ConfigError(f"{path}: no such file")
        if self.trusted_clients is not None:
            if self.certificate is None:
                raise ConfigError(
                    "--trusted-clients checks the certificates of encrypted connections: "
                    "give --certificate and --private-key too"
                )
            if not self.trusted_clients.is_dir():
                raise ConfigError(f"--trusted-clients {self.trusted_clients}: no such folder")
        if not is_loopback(parts.hostname) and (self.username is None or self.certificate is None):
            raise ConfigError(
                f"{where}: an address other than loopback needs a user (--user, "
                f"${PASSWORD_ENV}) and a server certificate (--certificate, --private-key); "
                "anonymous, unencrypted access is for this computer only"
            )
        return self


def _asyncua() -> Any:
    try:
        import asyncua
    except ImportError as exc:
        raise DependencyError(
            "the OPC UA server needs the package 'asyncua', which is missing "
            "(pip install 'ncmeasure[opcua]')"
        ) from exc
    return asyncua


_CERTIFICATE_SUFFIXES = (".pem", ".der", ".crt", ".cer")


def load_trusted_clients(folder: Path) -> list[Any]:
    """The certificates of a trust list folder: each ``*.pem``, ``*.der``, ``*.crt``, ``*.cer``.

    Raises:
        ConfigError: A file that is not one certificate (PEM or DER), or no certificate at all.
    """
    from cryptography import x509

    found = []
    try:
        paths = sorted(p for p in folder.iterdir() if p.suffix.lower() in _CERTIFICATE_SUFFIXES)
    except OSError as exc:
        raise ConfigError(f"--trusted-clients {folder}: {exc.strerror or exc}") from exc
    for path in paths:
        try:
            data = path.read_bytes()
            certificate = (
                x509.load_pem_x509_certificate(data)
                if b"-----BEGIN" in data
                else x509.load_der_x509_certificate(data)
            )
        except OSError as exc:
            raise ConfigError(f"{path}: cannot be read ({exc.strerror or exc})") from exc
        except ValueError as exc:
            raise ConfigError(
                f"{path}: not a certificate (PEM or DER); the --trusted-clients folder holds "
                "the clients' certificates or their CAs' and nothing else"
            ) from exc
        found.append(certificate)
    if not found:
        raise ConfigError(
            f"--trusted-clients {folder}: no certificate in it "
            f"({', '.join('*' + s for s in _CERTIFICATE_SUFFIXES)})"
        )
    return found


class TrustList:
    """Which client certificates may open a session: those in the list, or issued by a CA in it.

    Used as asyncua's certificate validator (called at CreateSession): an untrusted,
    expired or not yet valid client certificate is refused with BadCertificateUntrusted.
    """

    def __init__(self, certificates: list[Any]) -> None:
        from cryptography import x509
        from cryptography.hazmat.primitives.serialization import Encoding

        self._exact = {c.public_bytes(Encoding.DER) for c in certificates}
        self._cas = []
        for certificate in certificates:
            try:
                constraints = certificate.extensions.get_extension_for_class(
                    x509.BasicConstraints
                ).value
            except x509.ExtensionNotFound:
                continue
            if constraints.ca:
                self._cas.append(certificate)

    @staticmethod
    def _valid(certificate: Any, now: dt.datetime) -> bool:
        return bool(certificate.not_valid_before_utc <= now <= certificate.not_valid_after_utc)

    def trusts(self, certificate: Any, now: dt.datetime | None = None) -> bool:
        """True if ``certificate`` is valid now and in the list or issued by a CA in it."""
        from cryptography.exceptions import InvalidSignature
        from cryptography.hazmat.primitives.serialization import Encoding

        now = now or dt.datetime.now(dt.UTC)
        if not self._valid(certificate, now):
            return False
        if certificate.public_bytes(Encoding.DER) in self._exact:
            return True
        for ca in self._cas:
            if not self._valid(ca, now):
                continue
            try:
                certificate.verify_directly_issued_by(ca)
            except (ValueError, TypeError, InvalidSignature):
                continue
            return True
        return False

    async def __call__(self, certificate: Any, application: Any) -> None:
        from asyncua.common.utils import ServiceError
        from asyncua.ua.status_codes import StatusCodes

        if not self.trusts(certificate):
            _log.warning(
                "refused the client %s: its certificate (%s) is not trusted",
                getattr(application, "ApplicationUri", "?"),
                certificate.subject.rfc4514_string(),
            )
            raise ServiceError(StatusCodes.BadCertificateUntrusted)


def _read_overview(url: str, limits: Limits | None = None) -> FleetOverview:
    with open_store(url) as store:
        return fleet_overview(store, limits)


def serve_opcua(
    url: str,
    settings: OpcUaSettings,
    *,
    limits: Limits | None = None,
    on_ready: Callable[[str], None] | None = None,
    stop: threading.Event | None = None,
) -> None:
    """Serve the store at ``url`` over OPC UA until ``stop`` is set (blocking).

    Args:
        url: The store's URL.
        settings: Endpoint, refresh period, user, certificate.
        limits: The warning and critical limits of the change since the baseline
            (default: those of ``store report`` and the dashboard, 20 % and 40 %).
        on_ready: Called with the endpoint once clients can connect.
        stop: Set it to stop the server.

    Raises:
        ConfigError: Unusable settings; the address cannot be bound.
        DependencyError: asyncua is not installed.
        StoreError: The store cannot be opened.
        PublishError: The server cannot start (a certificate it cannot load).
    """
    settings = settings.checked()
    _asyncua()
    trust = (
        TrustList(load_trusted_clients(settings.trusted_clients))
        if settings.trusted_clients is not None
        else None
    )
    overview = _read_overview(url, limits)  # fails here, in words, before anything listens
    asyncio.run(_serve(url, settings, overview, trust, on_ready, stop or threading.Event()))


class _Users:
    """asyncua's user manager: everyone an ordinary (read-only) user, or the one named."""

    def __init__(self, settings: OpcUaSettings) -> None:
        self._name = settings.username
        self._password = settings.password

    def get_user(
        self, iserver: Any, username: str | None = None, password: str | None = None,
        certificate: Any = None,
    ) -> Any:  # fmt: skip
        from asyncua.crypto.permission_rules import User, UserRole

        if self._name is None:
            return User(role=UserRole.User)
        if (
            username == self._name
            and password is not None
            and self._password is not None
            and hmac.compare_digest(password.encode(), self._password.encode())
        ):
            return User(role=UserRole.User, name=username)
        return None


async def _serve(
    url: str,
    settings: OpcUaSettings,
    overview: FleetOverview,
    trust: TrustList | None,
    on_ready: Callable[[str], None] | None,
    stop: threading.Event,
) -> None:
    # asyncua's annotations want its own integer types (Int32, Int16) where ints work
    from asyncua import ua as ua_module
    from asyncua.common.structures104 import new_enum
    from asyncua.server.server import Server

    ua: Any = ua_module

    server = Server(user_manager=_Users(settings))  # type: ignore[arg-type]
    await server.init()
    server.set_endpoint(settings.endpoint)
    server.set_server_name("ncmeasure fleet store")
    server.allow_remote_admin(False)
    if settings.certificate is not None and settings.private_key is not None:
        try:
            await server.load_certificate(str(settings.certificate))
            await server.load_private_key(str(settings.private_key))
        except Exception as exc:  # asyncua raises what cryptography raises
            raise PublishError(
                f"{settings.certificate}, {settings.private_key}: not a usable certificate "
                f"and private key ({exc})"
            ) from exc
        server.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt])
        if trust is not None:
            server.set_certificate_validator(trust)
    else:
        server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
    tokens = [ua.UserNameIdentityToken] if settings.username else [ua.AnonymousIdentityToken]
    server.set_identity_tokens(tokens)
    ns = await server.register_namespace(NAMESPACE)
    di = await server.register_namespace(DI_NAMESPACE)
    health_type = await new_enum(
        server,
        ua.NodeId(DEVICE_HEALTH_TYPE_ID, di),
        ua.QualifiedName("DeviceHealthEnumeration", di),
        list(DEVICE_HEALTH),
    )
    space = _Space(server, ns, health_type.nodeid)
    await space.build_root()
    await space.update(overview)
    try:
        await server.start()
    except OSError as exc:
        host, port = settings.host_port
        raise ConfigError(
            f"cannot listen on {host}:{port}: {exc.strerror or exc} (another port: --endpoint)"
        ) from exc
    try:
        if on_ready is not None:
            on_ready(settings.endpoint)
        loop = asyncio.get_running_loop()
        next_refresh = loop.time() + settings.refresh_s
        while not stop.is_set():
            await asyncio.sleep(0.1)
            if loop.time() < next_refresh:
                continue
            next_refresh = loop.time() + settings.refresh_s
            try:
                overview = await asyncio.to_thread(_read_overview, url, overview.limits)
            except StoreError as exc:  # the last values stay; the next refresh tries again
                _log.warning("the store could not be read: %s", exc.message)
                continue
            await space.update(overview)
    finally:
        await server.stop()


def _timestamp(text: str | None) -> dt.datetime | None:
    if text is None:
        return None
    return dt.datetime.fromisoformat(text).astimezone(dt.UTC)


class _Space:
    """The nodes under Machines, created as machines and axes appear; values written on change."""

    def __init__(self, server: Any, ns: int, health_type: Any) -> None:
        from asyncua import ua

        self._ua: Any = ua
        self._server = server
        self._ns = ns
        self._health_type = health_type
        self._nodes: dict[str, Any] = {}
        self._values: dict[str, tuple[Any, ...]] = {}
        self._units: dict[str, str] = {}

    def _id(self, path: str) -> Any:
        return self._ua.NodeId(path, self._ns)

    def _name(self, name: str) -> Any:
        return self._ua.QualifiedName(name, self._ns)

    async def build_root(self) -> None:
        objects = self._server.nodes.objects
        self._nodes["Machines"] = await objects.add_folder(
            self._id("Machines"), self._name("Machines")
        )

    async def _object(self, path: str, name: str, parent: str, folder: bool = False) -> None:
        if path in self._nodes:
            return
        node = self._nodes[parent]
        add = node.add_folder if folder else node.add_object
        self._nodes[path] = await add(self._id(path), self._name(name))

    async def _set(
        self,
        path: str,
        value: Any,
        kind: str,
        *,
        when: dt.datetime | None = None,
        unit: str | None = None,
        datatype: Any = None,
    ) -> None:
        """Create the variable at ``path`` if new; write value, status and time if changed."""
        ua = self._ua
        variant_type = getattr(ua.VariantType, kind)
        parent, _, name = path.rpartition("/")
        if path not in self._nodes:
            initial = {"Double": math.nan, "String": "", "Int64": 0, "UInt32": 0, "Int32": 0}
            start = initial.get(kind, dt.datetime(1970, 1, 1, tzinfo=dt.UTC))
            self._nodes[path] = await self._nodes[parent].add_variable(
                self._id(path), self._name(name), ua.Variant(start, variant_type), datatype=datatype
            )
        if unit is not None and self._units.get(path) != unit:
            await self._engineering_units(path, unit)
        missing = value is None or (isinstance(value, float) and not math.isfinite(value))
        status = ua.StatusCodes.BadNoData if missing else ua.StatusCodes.Good
        shown = (math.nan if kind == "Double" else None) if missing else value
        key = (shown if not missing else "missing", status, when)
        if self._values.get(path) == key:
            return
        self._values[path] = key
        data = ua.DataValue(
            Value=ua.Variant(shown, variant_type) if shown is not None else ua.Variant(),
            StatusCode=ua.StatusCode(status),
            SourceTimestamp=when,
            ServerTimestamp=dt.datetime.now(dt.UTC),
        )
        await self._server.write_attribute_value(self._nodes[path].nodeid, data)

    async def _engineering_units(self, path: str, unit: str) -> None:
        ua = self._ua
        namespace, unit_id, display, description = engineering_units(unit)
        info = ua.EUInformation(
            NamespaceUri=namespace,
            UnitId=unit_id,
            DisplayName=ua.LocalizedText(display),
            Description=ua.LocalizedText(description),
        )
        key = f"{path}/EngineeringUnits"
        if key not in self._nodes:
            self._nodes[key] = await self._nodes[path].add_property(
                self._id(key),
                ua.QualifiedName("EngineeringUnits", 0),
                info,
                datatype=ua.NodeId(ua.ObjectIds.EUInformation),
            )
        else:
            await self._nodes[key].write_value(info)
        self._units[path] = unit

    async def update(self, overview: FleetOverview) -> None:
        """Bring every machine and axis to ``overview``."""
        await self._limit("WarningLimit", overview.limits.warning_percent)
        await self._limit("CriticalLimit", overview.limits.critical_percent)
        for machine in overview.machines:
            await self._machine(machine)

    async def _limit(self, name: str, percent: float) -> None:
        """A property of the Machines folder: a limit the changes are judged by, in %.

        Its NodeId is ``Limits/<name>``, apart from the machines' ``Machines/<serial>``.
        """
        path = f"Limits/{name}"
        if path in self._nodes:
            return
        ua = self._ua
        self._nodes[path] = await self._nodes["Machines"].add_property(
            self._id(path), self._name(name), ua.Variant(percent, ua.VariantType.Double)
        )
        await self._engineering_units(path, "%")

    async def _machine(self, machine: MachineOverview) -> None:
        base = f"Machines/{machine.serial}"
        await self._object(base, machine.serial, "Machines")
        await self._set(f"{base}/MachineType", machine.machine_type, "String")
        await self._set(f"{base}/Site", machine.site, "String")
        await self._set(f"{base}/Measurements", machine.measurements, "UInt32")
        healths = [device_health(axis) for axis in machine.axes.values()]
        when = _timestamp(machine.latest_utc)
        await self._health(f"{base}/DeviceHealth", worst_health(healths), when)
        await self._object(f"{base}/Axes", "Axes", base, folder=True)
        for axis in machine.axes.values():
            await self._axis(f"{base}/Axes/{axis.axis}", AxisSummary(machine, axis))

    async def _health(self, path: str, health: str, when: dt.datetime | None) -> None:
        await self._set(
            path,
            DEVICE_HEALTH[health],  # type: ignore[index]
            "Int32",
            when=when,
            datatype=self._health_type,
        )

    async def _axis(self, path: str, summary: AxisSummary) -> None:
        machine, axis = summary.machine, summary.axis
        await self._object(path, axis.axis, path.rsplit("/", 1)[0])
        when = _timestamp(machine.latest_utc)
        message = summary.message()
        unit = axis.unit
        for name, field, shown in (
            ("Coulomb", "coulomb", unit),
            ("Viscous", "viscous_per_m_min", f"{unit}/(m/min)"),
            ("Spread", "spread_percent", "%"),
            ("CoulombChange", "coulomb_change_percent", "%"),
            ("ViscousChange", "viscous_change_percent", "%"),
            ("SpreadChange", "spread_change_points", "pp"),
        ):
            await self._set(f"{path}/{name}", message[field], "Double", when=when, unit=shown)
        await self._set(f"{path}/Verdict", axis.verdict, "String", when=when)
        await self._set(f"{path}/Status", axis.status, "String", when=when)
        await self._set(f"{path}/MeasurementId", machine.latest_id, "Int64", when=when)
        await self._set(f"{path}/MeasuredTime", when, "DateTime", when=when)
        await self._health(f"{path}/DeviceHealth", summary.health, when)
