"""The live view's front end (:mod:`mems_sim.nodes.foxglove_front`) in front of a real
foxglove-sdk server, without ROS: Origin refused with 403, client cap with 503, both
subprotocol names, loopback sockets only, and the per-client queue that drops the oldest
message data of a client that does not read (counted) and keeps the control messages."""

from __future__ import annotations

import asyncio
import json
import os

import pytest
from proc_sockets import inet_sockets, is_loopback

from mems_sim.nodes.foxglove_front import ENTRY_OVERHEAD_BYTES, ClientQueue, FrontEnd
from mems_sim.nodes.foxglove_origin import OriginPolicy

TOPIC = "/front/test"


@pytest.fixture
def front():
    """(front end with at most 2 clients, its SDK channel, its log lines); stopped after."""
    import foxglove

    context = foxglove.Context()
    server = foxglove.start_server(host="127.0.0.1", port=0, context=context)
    channel = foxglove.Channel(
        TOPIC,
        schema=foxglove.Schema(name="std_msgs/msg/Empty", encoding="ros2msg", data=b""),
        message_encoding="cdr",
        context=context,
    )
    lines: list[str] = []
    fe = FrontEnd(server.port, "127.0.0.1", 0, OriginPolicy(), 2, 1 << 20, log=lines.append)
    fe.start()
    yield fe, channel, lines
    fe.stop()
    server.stop()


async def _server_info(port: int, origin=None, subprotocol="foxglove.sdk.v1"):
    """(negotiated subprotocol, first message's op) of one connection."""
    import websockets

    async with websockets.connect(
        f"ws://127.0.0.1:{port}", subprotocols=[subprotocol], origin=origin, proxy=None
    ) as ws:
        return ws.subprotocol, json.loads(await asyncio.wait_for(ws.recv(), 10))["op"]


def _status_of_refusal(port: int, **kw) -> int:
    import websockets

    with pytest.raises(websockets.exceptions.InvalidStatus) as refused:
        asyncio.run(_server_info(port, **kw))
    return refused.value.response.status_code


@pytest.mark.parametrize("origin", [None, "http://localhost:3000", "https://app.foxglove.dev"])
def test_an_allowed_origin_reaches_the_sdk_server(front, origin):
    fe, _, _ = front
    assert asyncio.run(_server_info(fe.port, origin=origin)) == ("foxglove.sdk.v1", "serverInfo")


def test_a_foreign_origin_is_refused_with_403_and_logged(front):
    fe, _, lines = front
    assert _status_of_refusal(fe.port, origin="https://evil.example") == 403
    assert fe.stats.refused_origin == 1 and fe.stats.accepted == 0
    assert any("https://evil.example" in line for line in lines)


def test_the_former_subprotocol_name_is_served_and_others_refused(front):
    fe, _, _ = front
    got = asyncio.run(_server_info(fe.port, subprotocol="foxglove.websocket.v1"))
    assert got == ("foxglove.websocket.v1", "serverInfo")
    assert _status_of_refusal(fe.port, subprotocol="chat") == 400


def test_one_client_beyond_max_clients_is_refused_with_503(front):
    import websockets

    fe, _, _ = front

    async def scenario():
        url = f"ws://127.0.0.1:{fe.port}"
        first = await websockets.connect(url, subprotocols=["foxglove.sdk.v1"], proxy=None)
        second = await websockets.connect(url, subprotocols=["foxglove.sdk.v1"], proxy=None)
        for ws in (first, second):
            await asyncio.wait_for(ws.recv(), 10)  # serverInfo: admitted
        with pytest.raises(websockets.exceptions.InvalidStatus) as refused:
            await websockets.connect(url, subprotocols=["foxglove.sdk.v1"], proxy=None)
        await first.close()
        for _ in range(200):  # the front end sees the close
            if fe.stats.clients < 2:
                break
            await asyncio.sleep(0.01)
        async with websockets.connect(url, subprotocols=["foxglove.sdk.v1"], proxy=None) as third:
            await asyncio.wait_for(third.recv(), 10)
        await second.close()
        return refused.value.response.status_code

    assert asyncio.run(scenario()) == 503
    assert fe.stats.refused_full == 1 and fe.stats.accepted == 3


def test_the_sdk_server_and_the_front_end_listen_on_loopback_only():
    import foxglove

    before = set(inet_sockets(os.getpid()))
    server = foxglove.start_server(host="127.0.0.1", port=0, context=foxglove.Context())
    fe = FrontEnd(server.port, "127.0.0.1", 0, OriginPolicy(), 2, 1 << 20)
    try:
        fe.start()
        new = set(inet_sockets(os.getpid())) - before
        ports = {int(address.rsplit(":", 1)[1]) for _, address in new}
        assert {server.port, fe.port} <= ports, new
        assert all(is_loopback(address) for _, address in new), new
    finally:
        fe.stop()
        server.stop()


def test_client_queue_drops_the_oldest_data_and_keeps_control_messages():
    async def scenario():
        queue = ClientQueue(limit_bytes=10 * (1000 + ENTRY_OVERHEAD_BYTES))
        queue.put('{"op":"advertise"}')
        for i in range(25):
            queue.put(bytes([1, i]) + bytes(998))
        assert queue.bytes <= queue.limit_bytes and not queue.overflowed
        assert queue.dropped == 16  # 25 data frames and one control message in 10 slots
        got = [await queue.get() for _ in range(len(queue))]
        assert got[0] == '{"op":"advertise"}'  # the control message survived, first
        assert [m[1] for m in got[1:]] == list(range(16, 25))  # the newest 9, in order
        return queue

    queue = asyncio.run(scenario())
    assert queue.bytes == 0


def test_client_queue_overflows_on_control_messages_alone():
    queue = ClientQueue(limit_bytes=3 * (100 + ENTRY_OVERHEAD_BYTES))
    for _ in range(3):
        queue.put("x" * 100)
    assert not queue.overflowed
    queue.put(b"\x01" + bytes(99))  # data is dropped before control is given up
    assert queue.dropped == 1 and not queue.overflowed
    queue.put("x" * 100)
    assert queue.overflowed and queue.dropped == 1


def test_client_queue_keeps_a_message_larger_than_its_bound_when_alone():
    queue = ClientQueue(limit_bytes=1000)
    queue.put(b"\x01" + bytes(5000))
    assert len(queue) == 1 and queue.dropped == 0 and not queue.overflowed
    queue.put(b"\x01" + bytes(10))  # the large one is the oldest: dropped for the newer
    assert len(queue) == 1 and queue.dropped == 1 and queue.bytes <= queue.limit_bytes
