"""The ``publish`` commands: the fleet store on the shop floor (MQTT, OPC UA)."""

import os
import threading
from pathlib import Path
from typing import Annotated

import typer

from ncmeasure.cli._app import (
    console,
    handle_errors,
    publish_app,
    restore_signals,
    stop_on_signals,
)
from ncmeasure.cli._fleet import mqtt_target, publish_stored
from ncmeasure.cli._options import CriticalOption, StoreOption, WarningOption, limits


@publish_app.command("mqtt")
@handle_errors
def publish_mqtt_command(
    url: Annotated[
        str,
        typer.Argument(
            help="The broker: mqtt://[USER@]HOST[:PORT][/PREFIX][?site=S&client_id=C&"
            "topic=T&protocol=5] or mqtts://...[?ca=FILE]. The password comes from "
            "$NCMEASURE_MQTT_PASSWORD, never from the command line.",
            show_default=False,
        ),
    ],
    serials: Annotated[
        list[str] | None,
        typer.Option(
            "--serial",
            metavar="SERIAL",
            help="Only this machine (repeat for several; default: all).",
        ),
    ] = None,
    warning: WarningOption = None,
    critical: CriticalOption = None,
    store: StoreOption = None,
) -> None:
    """Publish the latest fingerprint of every machine and axis of the store (retained, QoS 1).

    One JSON message per axis to PREFIX/SITE/SERIAL/AXIS/fingerprint (default prefix:
    ncmeasure): verdict, Coulomb and viscous friction, spread, their change since the
    baseline, DeviceHealth; docs/shop-floor.md describes every field. The status and
    health are those of `store report` with the same --warning/--critical.

    A broker that cannot be reached, refuses the user or a message: one line, exit 4.

    Example: NCMEASURE_MQTT_PASSWORD=... ncmeasure publish mqtt
    mqtts://line3@broker.plant?site=hall-2 --serial M17
    """
    chosen = limits(warning, critical)
    published = publish_stored(mqtt_target(url), store, serials, chosen)
    console().print(f"published {len(published.topics)} axis summaries to {published.target}")


@publish_app.command("opcua")
@handle_errors
def publish_opcua_command(
    store: StoreOption = None,
    endpoint: Annotated[
        str,
        typer.Option(help="Where to listen; anything but loopback needs --user and a certificate."),
    ] = "opc.tcp://127.0.0.1:4840",
    refresh_s: Annotated[
        float, typer.Option("--refresh-s", help="Read the store again every so many seconds.")
    ] = 10.0,
    warning: WarningOption = None,
    critical: CriticalOption = None,
    user: Annotated[
        str | None,
        typer.Option(
            help="The user clients log in as; the password from $NCMEASURE_OPCUA_PASSWORD."
        ),
    ] = None,
    certificate: Annotated[
        Path | None,
        typer.Option(
            help="The server's certificate (RSA, PEM or DER): the only endpoint is then "
            "Basic256Sha256, sign and encrypt."
        ),
    ] = None,
    private_key: Annotated[
        Path | None, typer.Option(help="The certificate's private key (PEM).")
    ] = None,
    trusted_clients: Annotated[
        Path | None,
        typer.Option(
            metavar="FOLDER",
            help="Only clients whose certificate, or the CA that issued it, is in this folder "
            "(*.pem, *.der, *.crt, *.cer) may connect; without it any client certificate "
            "opens the encrypted channel and the password decides.",
        ),
    ] = None,
) -> None:
    """The fleet store as an OPC UA server, until Ctrl-C: Machines → Machine → Axes → Axis.

    Each axis has its latest characteristics with engineering units and the measurement's
    time, and a DeviceHealth (OPC UA DI); docs/shop-floor.md draws the address space.
    The store is read again every --refresh-s: a new measurement reaches subscribers as
    a data change.

    Access: anonymous and read-only on loopback (the default endpoint). Any other address
    needs --user (password from $NCMEASURE_OPCUA_PASSWORD) and --certificate/--private-key;
    --trusted-clients limits who may connect. Nobody can write.

    Example: ncmeasure publish opcua --store postgresql://ncm@db/fleet

    Example: NCMEASURE_OPCUA_PASSWORD=... ncmeasure publish opcua --endpoint
    opc.tcp://0.0.0.0:4840 --user line3 --certificate server.pem --private-key server-key.pem
    --trusted-clients clients/
    """
    from ncmeasure.publish.opcua import PASSWORD_ENV, OpcUaSettings, serve_opcua
    from ncmeasure.store import store_url

    settings = OpcUaSettings(
        endpoint=endpoint,
        refresh_s=refresh_s,
        username=user,
        password=os.environ.get(PASSWORD_ENV),
        certificate=certificate,
        private_key=private_key,
        trusted_clients=trusted_clients,
    ).checked()
    chosen = limits(warning, critical)
    url = store_url(store)
    stop = threading.Event()
    previous = stop_on_signals(stop)
    try:
        serve_opcua(
            url,
            settings,
            limits=chosen,
            on_ready=lambda at: console().print(f"serving {url} at {at}; Ctrl-C stops"),
            stop=stop,
        )
    finally:
        restore_signals(previous)
    console().print("stopped")
