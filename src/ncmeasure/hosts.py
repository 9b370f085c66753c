"""Which host names and addresses are loopback: the rule the servers' defaults rest on.

The dashboard (:mod:`ncmeasure.web`) and the OPC UA server
(:mod:`ncmeasure.publish.opcua`) serve anonymously on a loopback address only;
both ask :func:`is_loopback`, which needs nothing beyond the standard library.
"""

from __future__ import annotations

import ipaddress

__all__ = ["is_loopback"]

_LOOPBACK_NAMES = frozenset({"localhost", "localhost.", "ip6-localhost"})


def is_loopback(host: str) -> bool:
    """True for ``localhost`` and loopback addresses (``127.0.0.0/8``, ``::1``)."""
    name = host.strip().lower()
    if name.startswith("[") and name.endswith("]"):
        name = name[1:-1]
    if name in _LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(name).is_loopback
    except ValueError:
        return False
