"""The live view's front door: a WebSocket proxy in front of the Foxglove SDK's server.

foxglove-sdk's server (0.30.3) has no hook on the handshake (no ``Origin`` check), no choice
of subprotocol and a per-client backlog counted in messages, not bytes. So the SDK's server
listens on a private port of 127.0.0.1 and :class:`FrontEnd` (on the ``websockets``
library) is what clients reach. For each client it:

- checks the handshake's ``Origin`` (:class:`~mems_sim.nodes.foxglove_origin.OriginPolicy`):
  refused with HTTP 403;
- caps the number of clients: one more is refused with HTTP 503;
- speaks ``foxglove.sdk.v1`` or, for older apps (Lichtblick, PlotJuggler), the identical
  protocol under its former name ``foxglove.websocket.v1``, and opens one connection to the
  SDK's server as ``foxglove.sdk.v1``;
- passes every message both ways, untouched; what goes to the client waits in a queue
  bounded in bytes (:class:`ClientQueue`): when the client does not read, the oldest message
  data frames are dropped, counted per client; control messages (JSON: advertisements,
  status) are never dropped, and a client whose control messages alone overflow the queue is
  disconnected.

It runs an asyncio loop in a thread of its own; the node calls :meth:`FrontEnd.start` and
:meth:`FrontEnd.stop`.
"""

from __future__ import annotations

import asyncio
import collections
import threading
from collections.abc import Callable
from dataclasses import dataclass

from mems_sim.nodes.foxglove_origin import OriginPolicy

#: Subprotocol names the front end accepts, preferred first; the SDK speaks the first.
SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")

#: Largest message a client may send [bytes] (subscriptions and other JSON requests).
CLIENT_MESSAGE_MAX_BYTES = 1 << 20

#: Messages the connection to the SDK's server reads ahead of the front end (websockets'
#: ``max_queue``; it holds more only while the front end's thread is starved of CPU).
BACKEND_QUEUE_FRAMES = 4

#: Bytes counted for a queued message besides its payload (the queue entry's own cost).
ENTRY_OVERHEAD_BYTES = 64

#: Longest wait for the front end to listen, or to stop [s].
START_STOP_TIMEOUT_S = 10.0

#: Close code of a client disconnected for reading too slowly (1008: policy violation).
CLOSE_TOO_SLOW = 1008


class ClientQueue:
    """What waits to be sent to one client, at most ``limit_bytes`` (payloads plus
    :data:`ENTRY_OVERHEAD_BYTES` each; a message alone in the queue is kept, however large).

    Binary messages (message data) are dropped oldest first while the queue is over its
    bound; text messages (control) are kept. :attr:`overflowed` turns true when control
    messages alone exceed the bound.
    """

    def __init__(self, limit_bytes: int) -> None:
        self.limit_bytes = limit_bytes
        self.dropped = 0
        self.overflowed = False
        self._items: collections.deque[str | bytes] = collections.deque()
        self._bytes = 0
        self._binary = 0
        self._ready = asyncio.Event()

    def __len__(self) -> int:
        return len(self._items)

    @property
    def bytes(self) -> int:
        """Bytes counted in the queue now."""
        return self._bytes

    def put(self, message: str | bytes) -> None:
        """Queue ``message``; drop the oldest binary messages while over the bound."""
        self._items.append(message)
        self._bytes += len(message) + ENTRY_OVERHEAD_BYTES
        self._binary += isinstance(message, bytes)
        if self._bytes > self.limit_bytes:
            self._shed()
        self._ready.set()

    def _shed(self) -> None:
        kept: list[str | bytes] = []
        while (
            self._bytes > self.limit_bytes and self._binary > 0 and len(self._items) + len(kept) > 1
        ):
            item = self._items.popleft()
            if isinstance(item, bytes):
                self._bytes -= len(item) + ENTRY_OVERHEAD_BYTES
                self._binary -= 1
                self.dropped += 1
            else:
                kept.append(item)
        self._items.extendleft(reversed(kept))
        self.overflowed = self._bytes > self.limit_bytes and self._binary == 0 and len(self) > 1

    async def get(self) -> str | bytes:
        """The oldest message (waits for one)."""
        while not self._items:
            self._ready.clear()
            await self._ready.wait()
        item = self._items.popleft()
        self._bytes -= len(item) + ENTRY_OVERHEAD_BYTES
        self._binary -= isinstance(item, bytes)
        return item


@dataclass
class FrontStats:
    """Counters of a front end since it started."""

    clients: int = 0  # connected now
    accepted: int = 0
    refused_origin: int = 0
    refused_full: int = 0
    dropped: int = 0  # messages dropped for clients that did not read, all clients
    disconnected_slow: int = 0


class FrontEnd:
    """The WebSocket server clients reach; a proxy to the SDK's server on ``backend_port``.

    Args:
        backend_port: TCP port of the SDK's server on 127.0.0.1.
        host: address to listen on.
        port: TCP port to listen on (0: any free port, :attr:`port` after :meth:`start`).
        policy: the allowed origins.
        max_clients: most clients connected at once.
        queue_bytes: bound of each client's outgoing queue [bytes].
        log: called with one line on each refusal, drop onset and disconnection (from the
            front end's thread).
    """

    def __init__(
        self,
        backend_port: int,
        host: str,
        port: int,
        policy: OriginPolicy,
        max_clients: int,
        queue_bytes: int,
        log: Callable[[str], None] = lambda line: None,
    ) -> None:
        self.backend_url = f"ws://127.0.0.1:{backend_port}"
        self.host = host
        self.port = port
        self.policy = policy
        self.max_clients = max_clients
        self.queue_bytes = queue_bytes
        self.stats = FrontStats()
        self._log = log
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._stopping: asyncio.Event | None = None

    # ---------------------------------------------------------------- life cycle

    def start(self) -> int:
        """Listen (in a thread of its own); the port listened on.

        Raises:
            OSError: the address cannot be listened on (e.g. the port is in use).
        """
        started = threading.Event()
        outcome: list = []
        self._thread = threading.Thread(
            target=self._run, args=(started, outcome), name="live_view front end", daemon=True
        )
        self._thread.start()
        if not started.wait(START_STOP_TIMEOUT_S):
            raise OSError(f"the front end did not listen within {START_STOP_TIMEOUT_S} s")
        if isinstance(outcome[0], BaseException):
            raise outcome[0]
        self.port = outcome[0]
        return self.port

    def _run(self, started: threading.Event, outcome: list) -> None:
        self._loop = asyncio.new_event_loop()
        try:
            self._loop.run_until_complete(self._serve(started, outcome))
        except BaseException as exc:  # reported to start(); a bind failure is an OSError
            if not started.is_set():
                outcome.append(exc)
                started.set()
        finally:
            self._loop.close()

    async def _serve(self, started: threading.Event, outcome: list) -> None:
        from websockets.asyncio.server import serve

        self._stopping = asyncio.Event()
        async with serve(
            self._handle,
            self.host,
            self.port,
            process_request=self._admit,
            subprotocols=list(SUBPROTOCOLS),
            compression=None,
            max_size=CLIENT_MESSAGE_MAX_BYTES,
        ) as server:
            outcome.append(server.sockets[0].getsockname()[1])
            started.set()
            await self._stopping.wait()
            server.close()

    def stop(self) -> None:
        """Close every client and the server; wait for the thread (idempotent)."""
        if self._thread is None or self._loop is None or self._stopping is None:
            return
        if self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._stopping.set)
            self._thread.join(START_STOP_TIMEOUT_S)
        self._thread = None

    # ---------------------------------------------------------------- handshake

    def _admit(self, connection, request):
        """``process_request``: 403 for a refused origin, 503 when full; None admits."""
        origin = request.headers.get("Origin")
        if not self.policy.allows(origin):
            self.stats.refused_origin += 1
            self._log(f"refused a client from origin {origin!r} (not allowed_origins)")
            return connection.respond(
                403, f"Origin {origin} not allowed: add it to the live view's allowed_origins\n"
            )
        if self.stats.clients >= self.max_clients:
            self.stats.refused_full += 1
            self._log(f"refused a client: {self.max_clients} clients connected (max_clients)")
            return connection.respond(
                503, f"The live view serves at most {self.max_clients} clients (max_clients)\n"
            )
        return None

    # ---------------------------------------------------------------- one client

    async def _handle(self, client) -> None:
        from websockets.asyncio.client import connect

        if self.stats.clients >= self.max_clients:  # handshakes that raced past _admit
            self.stats.refused_full += 1
            await client.close(1013, "too many clients (max_clients)")
            return
        self.stats.clients += 1
        self.stats.accepted += 1
        queue = ClientQueue(self.queue_bytes)
        try:
            async with connect(
                self.backend_url,
                subprotocols=[SUBPROTOCOLS[0]],
                compression=None,
                max_size=None,
                max_queue=BACKEND_QUEUE_FRAMES,
                proxy=None,
            ) as backend:
                await self._pump(client, backend, queue)
        except OSError as exc:
            self._log(f"the SDK's server refused a client's connection ({exc})")
        finally:
            self.stats.clients -= 1
            if queue.dropped:
                self._log(
                    f"client {_peer(client)} left: {queue.dropped} messages dropped for it "
                    "(it did not read them in time)"
                )

    async def _pump(self, client, backend, queue: ClientQueue) -> None:
        """Run the three directions until one ends, then close both connections."""
        tasks = [
            asyncio.ensure_future(self._upstream(client, backend)),
            asyncio.ensure_future(self._downstream(backend, queue, client)),
            asyncio.ensure_future(self._deliver(queue, client)),
        ]
        stop = asyncio.ensure_future(self._stopping.wait())
        await asyncio.wait([*tasks, stop], return_when=asyncio.FIRST_COMPLETED)
        for task in [*tasks, stop]:
            task.cancel()
        await asyncio.gather(*tasks, stop, return_exceptions=True)
        await asyncio.gather(backend.close(), client.close(), return_exceptions=True)

    @staticmethod
    async def _upstream(client, backend) -> None:
        from websockets.exceptions import ConnectionClosed

        try:
            async for message in client:
                await backend.send(message)
        except ConnectionClosed:
            pass

    async def _downstream(self, backend, queue: ClientQueue, client) -> None:
        from websockets.exceptions import ConnectionClosed

        try:
            async for message in backend:
                before = queue.dropped
                queue.put(message)
                self.stats.dropped += queue.dropped - before
                if queue.dropped and not before:
                    self._log(
                        f"client {_peer(client)} does not keep up: dropping its oldest "
                        f"messages (queue bound {self.queue_bytes} bytes)"
                    )
                if queue.overflowed:
                    self.stats.disconnected_slow += 1
                    self._log(f"client {_peer(client)} disconnected: it reads nothing")
                    await client.close(CLOSE_TOO_SLOW, "client too slow")
                    return
        except ConnectionClosed:
            pass

    @staticmethod
    async def _deliver(queue: ClientQueue, client) -> None:
        from websockets.exceptions import ConnectionClosed

        try:
            while True:
                await client.send(await queue.get())
        except ConnectionClosed:
            pass


def _peer(connection) -> str:
    """``host:port`` of a connection's remote end."""
    address = connection.remote_address
    return f"{address[0]}:{address[1]}" if address else "?"
