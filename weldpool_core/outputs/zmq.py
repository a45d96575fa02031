"""Each record as one JSON message on a ZeroMQ XPUB socket (subscribers use a SUB socket and
subscribe to ""; the manual's "The live view and the welding cell" has a five-line subscriber).

The socket is verbose (``XPUB_VERBOSER``): every subscribe and unsubscribe reaches it, so it counts
its subscribers. A subscriber that stops reading fills its own queue (ZeroMQ's high-water mark)
and loses its messages there; the others and the inference thread go on.
"""

from __future__ import annotations

import json
import time
from typing import Any

from weldpool_core.errors import InvalidInputError
from weldpool_core.outputs.base import CellInfo, Counters, OutputStatus


class Publisher:
    """Records as JSON messages on a ZeroMQ XPUB socket bound to ``address``.

    ``wait_for_subscriber(seconds)`` blocks until a subscriber has joined (XPUB sees its
    subscription), so that a controller started first misses no frame.
    """

    kind = "zeromq"

    def __init__(self, address: str) -> None:
        import zmq

        self._zmq = zmq
        self._context: Any = zmq.Context.instance()
        self._socket = self._context.socket(zmq.XPUB)
        self._socket.setsockopt(zmq.LINGER, 500)
        self._socket.setsockopt(zmq.XPUB_VERBOSER, 1)
        try:
            self._socket.bind(address)
        except zmq.ZMQError as exc:
            self._socket.close()
            raise InvalidInputError(f"Cannot publish on {address!r}: {exc}.") from exc
        self.address = address
        self.subscribers = 0
        self.counters = Counters()

    def _read_subscriptions(self, timeout_ms: int = 0) -> None:
        """Count the (un)subscriptions that arrived (each a message: 1 or 0, then the topic)."""
        zmq = self._zmq
        while self._socket.poll(timeout_ms, zmq.POLLIN):
            message = self._socket.recv()
            if message[:1] == b"\x01":
                self.subscribers += 1
            elif message[:1] == b"\x00":
                self.subscribers = max(0, self.subscribers - 1)
            timeout_ms = 0

    def wait_for_subscriber(self, seconds: float) -> bool:
        """True once a subscriber has subscribed; False after ``seconds`` without one."""
        deadline = time.perf_counter() + seconds
        while self.subscribers == 0:
            left = deadline - time.perf_counter()
            if left <= 0:
                return False
            self._read_subscriptions(max(1, int(left * 1000)))
        return True

    def send(self, record: dict[str, Any]) -> None:
        since = time.perf_counter()
        self._read_subscriptions()
        self._socket.send(json.dumps(record, separators=(",", ":")).encode())
        self.counters.added(since)

    def status(self) -> OutputStatus:
        # The count as of the last frame sent: a ZeroMQ socket belongs to the thread that sends.
        p50, p99 = self.counters.percentiles()
        return OutputStatus(
            self.kind,
            self.address,
            "closed" if self._socket.closed else "bound",
            self.subscribers,
            self.counters.sent,
            0,
            p50,
            p99,
        )

    def close(self) -> None:
        self._socket.close()


def open_output(address: str, _info: CellInfo) -> Publisher:
    """The ZeroMQ output of the registry (``weldpool_core.outputs.OUTPUTS``)."""
    return Publisher(address)
