"""What the OPC UA tests' asyncua clients share: a subscription whose changes land in a queue."""

from __future__ import annotations

import asyncio
from typing import Any


async def subscribe_changes(client: Any, node: Any) -> tuple[Any, asyncio.Queue[Any]]:
    """Subscribe to ``node``'s value (100 ms); the subscription, and a queue
    that each data change is put into.

    The first one is the current value, as an OPC UA server sends it on subscribing.
    """
    changes: asyncio.Queue[Any] = asyncio.Queue()

    class Handler:
        def datachange_notification(self, node: Any, val: Any, data: Any) -> None:
            changes.put_nowait(val)

    subscription = await client.create_subscription(100, Handler())
    await subscription.subscribe_data_change(node)
    return subscription, changes
