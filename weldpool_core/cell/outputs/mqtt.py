"""Each record as one compact JSON message on an MQTT topic (paho-mqtt), the shop floor's bus.

``mqtt://[user@]host[:port]/topic`` (``mqtts://`` for TLS, port 8883 by default). The message is
``CellRecord.message()`` (the same values as the OPC UA variables). QoS 0 by default (a lost
frame is replaced by the next one); QoS 1 and retain are options. ``rate_hz`` publishes at most
that many messages a second (the newest record each time), for a dashboard that needs no more.

``<topic>/status`` carries a retained ``{"state": …}``: ``online`` at connect, ``stale`` when no
frame comes for ``stale_ms``, ``offline`` at the end, and — as the broker's last will — when the
stream dies without saying so.

paho's network thread connects, reconnects (1 s to 30 s back-off) and writes; ``send`` only hands
it a message, so a broker that goes away never blocks inference: while it is gone, messages are
dropped and counted (``skipped``), and the outage is logged once when it starts and once when it
ends.
"""

from __future__ import annotations

import contextlib
import json
import select
import socket
import ssl
import threading
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import unquote, urlparse

from weldpool_core.cell.outputs.base import CellInfo, CellRecord, Counters, OutputStatus, Reporter
from weldpool_core.errors import InvalidInputError

KEEPALIVE_S = 10
MAX_QUEUED = 64
"""Messages paho may hold for a QoS 1 publish while the broker does not acknowledge."""


@dataclass(frozen=True)
class MqttOptions:
    """Where and how the messages go."""

    url: str
    qos: int = 0
    retain: bool = False
    rate_hz: float | None = None
    username: str | None = None
    password: str | None = None
    ca_file: Path | None = None
    cert_file: Path | None = None
    key_file: Path | None = None


@dataclass(frozen=True)
class MqttTarget:
    host: str
    port: int
    topic: str
    tls: bool
    username: str | None
    password: str | None


def parse_mqtt_url(url: str) -> MqttTarget:
    """The broker and topic of ``mqtt[s]://[user[:password]@]host[:port]/topic``."""
    parsed = urlparse(url)
    shown = _without_password(url)  # errors go to logs and API answers: never the password
    if parsed.scheme not in ("mqtt", "mqtts") or not parsed.hostname:
        raise InvalidInputError(
            f"{shown!r} is not an MQTT address; give mqtt://HOST[:PORT]/TOPIC (mqtts:// for TLS)."
        )
    topic = unquote(parsed.path.lstrip("/"))
    if not topic or "#" in url or parsed.query or any(c in topic for c in "+\0"):
        raise InvalidInputError(
            f"{shown!r} needs a topic without wildcards after the host, e.g. mqtt://broker/cell1/pool."
        )
    try:
        port = parsed.port or (8883 if parsed.scheme == "mqtts" else 1883)
    except ValueError:
        raise InvalidInputError(f"The port of {shown!r} is not a number from 1 to 65535.") from None
    return MqttTarget(
        parsed.hostname,
        port,
        topic,
        parsed.scheme == "mqtts",
        unquote(parsed.username) if parsed.username else None,
        unquote(parsed.password) if parsed.password else None,
    )


def check_broker_host(url: str) -> None:
    """Refuse a broker host name that does not resolve (a typo), before anything starts. A host
    that resolves but does not answer is not refused: the publisher connects when it comes up."""
    target = parse_mqtt_url(url)
    try:
        socket.getaddrinfo(target.host, target.port, type=socket.SOCK_STREAM)
    except OSError:
        raise InvalidInputError(
            f"The MQTT broker's host {target.host!r} does not resolve; check the address."
        ) from None


class _Poll:
    """``select.select`` for paho's network loop, answered by ``poll``. ``select`` refuses a
    descriptor of 1024 or more, so in a process holding that many files (a server with many
    connections, a long test run) paho's loop lost every connection it made, silently."""

    @staticmethod
    def select(
        rlist: list[Any], wlist: list[Any], _x: list[Any], timeout: float | None = None
    ) -> tuple[list[Any], list[Any], list[Any]]:
        objects: dict[int, Any] = {}
        masks: dict[int, int] = {}
        for mask, group in ((select.POLLIN, rlist), (select.POLLOUT, wlist)):
            for item in group:
                fd = item if isinstance(item, int) else item.fileno()
                if fd < 0:  # a closed socket: as select says it
                    raise ValueError("file descriptor cannot be a negative integer")
                objects[fd], masks[fd] = item, masks.get(fd, 0) | mask
        poller = select.poll()
        for fd, mask in masks.items():
            poller.register(fd, mask)
        ready = poller.poll(None if timeout is None else max(0.0, timeout) * 1000)
        broken = select.POLLERR | select.POLLHUP | select.POLLNVAL
        readable = [objects[fd] for fd, ev in ready if ev & (select.POLLIN | broken)]
        writable = [objects[fd] for fd, ev in ready if ev & select.POLLOUT]
        return (
            [item for item in readable if item in rlist],
            [item for item in writable if item in wlist],
            [],
        )


def poll_paho() -> None:
    """Make paho's network loop wait with ``poll`` instead of ``select`` (``_Poll``)."""
    import paho.mqtt.client as mqtt

    mqtt.select = _Poll  # type: ignore[attr-defined,assignment]


class MqttPublisher:
    """The stream's records on an MQTT topic (see the module doc)."""

    kind = "mqtt"

    def __init__(self, options: MqttOptions, info: CellInfo) -> None:
        import paho.mqtt.client as mqtt
        from paho.mqtt.enums import CallbackAPIVersion

        poll_paho()
        target = parse_mqtt_url(options.url)
        if options.qos not in (0, 1):
            raise InvalidInputError(f"--mqtt-qos must be 0 or 1, not {options.qos}.")
        for path in (options.ca_file, options.cert_file, options.key_file):
            if path is not None and not path.is_file():
                raise InvalidInputError(f"There is no file {str(path)!r} for MQTT's TLS.")
        self.address = _without_password(options.url)
        self.options = options
        self.info = info
        self.topic = target.topic
        self.status_topic = f"{target.topic}/status"
        self.counters = Counters()
        self.reporter = Reporter(f"MQTT {self.address}")
        self._connected = threading.Event()
        self._ever_connected = False
        self._ok, self._full = mqtt.MQTT_ERR_SUCCESS, mqtt.MQTT_ERR_QUEUE_SIZE
        self._pending: tuple[dict[str, Any], float] | None = None
        self._lock = threading.Lock()
        self._closing = False
        client = mqtt.Client(
            CallbackAPIVersion.VERSION2,
            client_id=f"weldpool-stream-{uuid.uuid4().hex[:8]}",
            protocol=mqtt.MQTTv311,
        )
        username = options.username or target.username
        password = options.password if options.password is not None else target.password
        if username:
            client.username_pw_set(username, password)
        if target.tls or options.ca_file:
            client.tls_set(
                ca_certs=str(options.ca_file) if options.ca_file else None,
                certfile=str(options.cert_file) if options.cert_file else None,
                keyfile=str(options.key_file) if options.key_file else None,
                cert_reqs=ssl.CERT_REQUIRED,
            )
        client.max_queued_messages_set(MAX_QUEUED)
        client.reconnect_delay_set(1, 30)
        client.will_set(self.status_topic, _state("offline"), qos=1, retain=True)
        client.on_connect = self._on_connect
        client.on_disconnect = self._on_disconnect
        self._client = client
        try:
            client.connect_async(target.host, target.port, keepalive=KEEPALIVE_S)
        except (OSError, ValueError) as exc:
            raise InvalidInputError(f"Cannot use the MQTT broker {self.address!r}: {exc}.") from exc
        client.loop_start()
        self._flusher: threading.Thread | None = None
        self._flush_stop = threading.Event()
        if options.rate_hz:
            self._flusher = threading.Thread(target=self._flush, name="mqtt-rate", daemon=True)
            self._flusher.start()

    def wait_for_subscriber(self, seconds: float) -> bool:
        """True once the broker has accepted the connection (False after ``seconds``): an MQTT
        publisher knows its broker, not its subscribers."""
        return self._connected.wait(seconds)

    def send(self, record: dict[str, Any]) -> None:
        since = time.perf_counter()
        if self.options.rate_hz:
            with self._lock:
                if self._pending is not None:
                    self.counters.skipped += 1
                self._pending = (record, since)
            return
        with self._lock:
            self._publish(record, since)

    def _flush(self) -> None:
        assert self.options.rate_hz
        period = 1.0 / self.options.rate_hz
        while not self._flush_stop.wait(period):
            self._flush_pending()

    def _flush_pending(self) -> None:
        with self._lock:
            pending, self._pending = self._pending, None
            if pending is not None:
                self._publish(*pending)

    def _publish(self, record: dict[str, Any], since: float) -> None:
        """One message (called holding ``_lock``: the counters have one writer at a time)."""
        if not self._connected.is_set():
            self.counters.skipped += 1
            return
        payload = json.dumps(CellRecord.of(record, self.info).message(), separators=(",", ":"))
        info = self._client.publish(
            self.topic, payload, qos=self.options.qos, retain=self.options.retain
        )
        if info.rc == self._ok:
            self.counters.added(since)
            self.reporter.resolved("queue", "the broker takes messages again")
        else:
            self.counters.skipped += 1
            if info.rc == self._full:
                self.reporter.problem(
                    "queue",
                    f"the broker does not acknowledge; {MAX_QUEUED} messages wait, newer ones "
                    "are dropped",
                )

    def stale(self, quiet_ms: float) -> None:
        if self._connected.is_set():
            self._client.publish(
                self.status_topic, _state("stale", quiet_ms=round(quiet_ms)), qos=1, retain=True
            )

    def resumed(self) -> None:
        """Frames come again after a pause: the status says ``online`` again."""
        if self._connected.is_set():
            self._client.publish(
                self.status_topic, _state("online", model=self.info.model), 1, True
            )

    def _on_connect(self, client: Any, _data: Any, _flags: Any, reason: Any, _props: Any) -> None:
        if reason.is_failure:
            self.reporter.problem("connect", f"the broker refused the connection ({reason})")
            return
        self.reporter.resolved("connect", "connected")
        self.reporter.resolved("down", "the broker is back; publishing again")
        self._ever_connected = True
        client.publish(self.status_topic, _state("online", model=self.info.model), 1, True)
        self._connected.set()

    def _on_disconnect(
        self, _client: Any, _data: Any, _flags: Any, reason: Any, _props: Any
    ) -> None:
        self._connected.clear()
        if not self._closing and self._ever_connected:  # a refusal is told by _on_connect
            self.reporter.problem(
                "down",
                f"the broker went away ({reason}); reconnecting, frames are dropped meanwhile",
            )

    def status(self) -> OutputStatus:
        p50, p99 = self.counters.percentiles()
        if self._closing:  # closed here (the view or stream stopped): not the broker's doing
            state = "disconnected"
        elif self._connected.is_set():
            state = "connected"
        else:
            state = "reconnecting" if self._ever_connected else "connecting"
        return OutputStatus(
            self.kind,
            self.address,
            state,
            None,  # an MQTT publisher cannot know its subscribers: the broker does
            self.counters.sent,
            self.counters.skipped,
            p50,
            p99,
        )

    def close(self) -> None:
        self._flush_stop.set()
        if self._flusher is not None:
            self._flusher.join(timeout=2)
            self._flush_pending()  # the last frame is not lost to the rate
        self._closing = True
        if self._connected.is_set():
            info = self._client.publish(self.status_topic, _state("offline"), qos=1, retain=True)
            with contextlib.suppress(RuntimeError, ValueError):
                info.wait_for_publish(timeout=2)
        self._client.disconnect()
        self._client.loop_stop()


def _state(state: str, **extra: Any) -> str:
    return json.dumps({"state": state, "t": round(time.time(), 3), **extra})


def _without_password(url: str) -> str:
    parsed = urlparse(url)
    if parsed.password is None:
        return url
    netloc = parsed.netloc.replace(f":{parsed.password}@", ":***@", 1)
    return parsed._replace(netloc=netloc).geturl()


def open_output(options: MqttOptions, info: CellInfo) -> MqttPublisher:
    """The MQTT output of the registry (``weldpool_core.cell.outputs.OUTPUTS``): a broker host that
    does not resolve is refused at once, in one sentence."""
    check_broker_host(options.url)
    return MqttPublisher(options, info)
