"""The MQTT bridge's publishing tasks end when cancelled, even when a publish swallows the
cancellation (asyncio.wait_for before Python 3.12, inside aiomqtt, does when the broker's
acknowledgement arrives with it): the server's stop would otherwise wait forever."""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Coroutine
from typing import Any

import pytest

from tmcl_server.clock import VirtualClock
from tmcl_server.module import TMCM6212
from tmcl_server.simulation import Simulation
from tmcl_server.transports.mqtt.bridge import MqttBridge, _Outgoing

WAIT_S = 5.0  # a fail-safe for an end that is due


class SwallowingClient:
    """Stands in for aiomqtt.Client: its publish returns normally when cancelled."""

    def __init__(self) -> None:
        self.publishing = asyncio.Event()

    async def publish(self, *args: Any, **kwargs: Any) -> None:
        self.publishing.set()
        try:
            await asyncio.Event().wait()  # the acknowledgement, never due here
        except asyncio.CancelledError:
            return  # as wait_for does when the result is there too


@pytest.mark.parametrize("publisher", [MqttBridge._publish_outbox, MqttBridge._publish_state])
def test_a_swallowed_cancellation_still_ends_the_task(
        publisher: Callable[[MqttBridge, Any], Coroutine[Any, Any, None]]) -> None:
    async def scenario() -> None:
        bridge = MqttBridge(Simulation([TMCM6212()], VirtualClock()), "mqtt://127.0.0.1:1/t")
        bridge.enqueue(_Outgoing("t/1/event", b"{}"))
        client = SwallowingClient()
        task = asyncio.create_task(publisher(bridge, client))
        await asyncio.wait_for(client.publishing.wait(), WAIT_S)
        task.cancel()
        done, _ = await asyncio.wait({task}, timeout=WAIT_S)
        assert task in done, "the task went on after its cancellation"
        assert task.cancelled()

    asyncio.run(scenario())
