"""The fleet store and the MQTT broker, as the commands that store or publish open them.

``analyze --store --publish``, the ``store`` commands and ``publish mqtt`` share these.
"""

from typing import Any

from ncmeasure.cli._app import console


def open_store(url: str | None, *, write: bool) -> Any:
    """The store module's ``open_store`` context on the resolved URL; a clear error
    naming the extra when SQLAlchemy is missing."""
    try:
        from ncmeasure.store import open_store as open_fleet_store
        from ncmeasure.store import store_url
    except ImportError as exc:
        from ncmeasure.errors import DependencyError

        raise DependencyError(
            f"the fleet store needs the package {exc.name!r}, which is missing "
            "(pip install 'ncmeasure[store]')"
        ) from exc
    return open_fleet_store(store_url(url), write=write)


def measurement_info(**fields: Any) -> Any:
    """The store's ``MeasurementInfo`` of these fields, checked."""
    from ncmeasure.store import measurement_info as checked_info

    return checked_info(**fields)


def mqtt_target(url: str | None) -> Any:
    """The broker of ``--publish``/``publish mqtt`` (None: none), checked before anything
    is stored or read; paho-mqtt's absence is found here too."""
    if url is None:
        return None
    from ncmeasure.publish.mqtt import MqttTarget, paho

    paho()
    return MqttTarget.from_url(url)


def publish_stored(
    target: Any, store: str | None, serials: list[str] | None, limits: Any = None
) -> Any:
    """Publish the axis summaries of these machines (None: all) of the store."""
    from ncmeasure.publish import axis_summaries
    from ncmeasure.publish.mqtt import publish_summaries
    from ncmeasure.store.overview import fleet_overview

    with open_store(store, write=False) as fleet:
        summaries = axis_summaries(fleet_overview(fleet, limits), serials)
    return publish_summaries(target, summaries)


def publish_added(target: Any, store: str | None, added: Any, quiet: bool) -> None:
    """Publish the machine just stored; a failure says that the measurement stays stored."""
    if target is None:
        return
    from ncmeasure.errors import PublishError

    try:
        published = publish_stored(target, store, [added.serial])
    except PublishError as exc:
        raise PublishError(
            f"measurement {added.measurement_id} of {added.serial} is stored, but was not "
            f"published: {exc.message} (`ncmeasure publish mqtt` sends it later)"
        ) from exc
    if not quiet:
        console().print(f"published {len(published.topics)} axis summaries to {published.target}")
