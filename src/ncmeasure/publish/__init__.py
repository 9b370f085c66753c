"""The fleet store on the shop floor: MQTT messages and an OPC UA server.

Both speak of the same thing, one summary per machine and axis built from what
the store already computes (:func:`~ncmeasure.store.overview.fleet_overview`:
the latest verdict, the change of each characteristic since the baseline, the
outliers of the type), and the same health state per axis, the OPC UA DI
``DeviceHealth`` (:mod:`ncmeasure.publish.summary`).

* :mod:`ncmeasure.publish.mqtt`: publish the summaries as retained JSON
  messages to a broker (paho-mqtt; extra ``mqtt``).
* :mod:`ncmeasure.publish.opcua`: serve the store as an OPC UA address space
  (asyncua; extra ``opcua``).

docs/shop-floor.md describes the topic tree, the message and the address space.
"""

from __future__ import annotations

from ncmeasure.publish.summary import (
    DEVICE_HEALTH,
    SUMMARY_SCHEMA,
    AxisSummary,
    axis_summaries,
    device_health,
)

__all__ = [
    "DEVICE_HEALTH",
    "SUMMARY_SCHEMA",
    "AxisSummary",
    "axis_summaries",
    "device_health",
]
