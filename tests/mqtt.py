"""The MQTT broker the suite runs against: Debian's mosquitto on 127.0.0.1.

`.ci/run` installs and starts it and sets WELDPOOL_TEST_MQTT_URL; the suite then fails, not
skips, when it does not answer. Without that variable (a developer's machine) the first test that
needs it starts ``mosquitto`` on a free port. ``start_broker`` starts a private one a test may
stop (a broker that goes away)."""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import urlparse

import paho.mqtt.client as mqtt
import pytest

URL_VARIABLE = "WELDPOOL_TEST_MQTT_URL"


def unique_topic(name: str) -> str:
    """A topic no earlier run has used: a shared broker (CI's, a developer's with persistence)
    may still hold retained status messages of the same test from before."""
    return f"weldpool-test/{uuid.uuid4().hex[:12]}/{name}"


def clear_retained(host: str, port: int, topic: str) -> None:
    """Remove ``topic``'s retained message from a shared broker (an empty retained payload)."""
    import paho.mqtt.client as mqtt

    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
    client.connect(host, port)
    client.loop_start()
    try:
        client.publish(topic, b"", qos=1, retain=True).wait_for_publish(5)
    finally:
        client.loop_stop()
        client.disconnect()


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def answers(host: str, port: int) -> bool:
    try:
        with socket.create_connection((host, port), timeout=2):
            return True
    except OSError:
        return False


def start_broker(
    folder: Path, port: int | None = None, settings: str = "allow_anonymous true\n"
) -> tuple[subprocess.Popen[bytes], int]:
    """A mosquitto of its own on 127.0.0.1 (``port`` or a free one), answering; ``settings`` are
    the listener's lines (TLS files, a password file)."""
    binary = shutil.which("mosquitto") or (
        "/usr/sbin/mosquitto" if Path("/usr/sbin/mosquitto").exists() else None
    )
    if binary is None:
        pytest.fail(
            "mosquitto is missing: apt-get install mosquitto (.ci/run does).", pytrace=False
        )
    port = port or free_port()
    config = folder / f"mosquitto-{port}.conf"
    # As root, mosquitto would drop to its own user, who cannot read the test's files.
    user = "user root\n" if os.geteuid() == 0 else ""
    config.write_text(f"{user}listener {port} 127.0.0.1\npersistence false\n{settings}")
    log = open(folder / f"mosquitto-{port}.log", "wb")  # noqa: SIM115
    process = subprocess.Popen([binary, "-c", str(config)], stdout=log, stderr=subprocess.STDOUT)
    deadline = time.monotonic() + 20
    while not answers("127.0.0.1", port):
        if time.monotonic() > deadline or process.poll() is not None:
            process.kill()
            pytest.fail(f"mosquitto did not start on port {port}.", pytrace=False)
        time.sleep(0.05)
    return process, port


@pytest.fixture(scope="session")
def mqtt_broker(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, int]]:
    """Host and port of a real MQTT broker (fails when CI's does not answer)."""
    given = os.environ.get(URL_VARIABLE)
    if given:
        parsed = urlparse(given)
        host, port = parsed.hostname or "127.0.0.1", parsed.port or 1883
        if not answers(host, port):
            pytest.fail(
                f"The MQTT broker at {given} ({URL_VARIABLE}) does not answer; start mosquitto. "
                "The suite must run against a real broker.",
                pytrace=False,
            )
        yield host, port
        return
    process, port = start_broker(tmp_path_factory.mktemp("mosquitto"))
    yield "127.0.0.1", port
    process.terminate()
    process.wait(timeout=10)


class Listener:
    """A subscriber on ``topic/#`` that keeps what it receives."""

    def __init__(self, host: str, port: int, topic: str) -> None:
        self.topic = topic
        self.url = f"mqtt://{host}:{port}/{topic}"
        self.messages: list[tuple[str, Any]] = []
        self.ready = threading.Event()
        self.connected: list[str] = []
        # A connection that gets no CONNACK is tried again with a fresh client (and socket);
        # the failure says what the broker answered.
        for _ in range(3):
            self.client = self._connect(host, port)
            if self.ready.wait(8):
                return
            self.client.loop_stop()
            self.client.disconnect()
        raise AssertionError(f"no SUBACK for {topic}/# from {host}:{port}: {self.connected}")

    def _connect(self, host: str, port: int) -> mqtt.Client:
        from weldpool_core.cell.outputs.mqtt import poll_paho

        poll_paho()  # a long suite holds over 1,023 files: select() would refuse the socket
        client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
        client.on_message = lambda _c, _u, m: (
            self.messages.append((m.topic, json.loads(m.payload))) if m.payload else None
        )
        client.on_subscribe = lambda *_args: self.ready.set()
        client.on_connect = self._subscribe
        client.connect(host, port)
        client.loop_start()
        return client

    def _subscribe(
        self, client: mqtt.Client, _data: Any, _flags: Any, reason: Any, *_: Any
    ) -> None:
        self.connected.append(str(reason))
        client.subscribe(f"{self.topic}/#", qos=1)

    def frames(self, topic: str) -> list[dict[str, Any]]:
        return [payload for name, payload in self.messages if name == topic]

    def wait_for(self, predicate: Any, seconds: float = 10) -> None:
        deadline = time.monotonic() + seconds
        while not predicate() and time.monotonic() < deadline:
            time.sleep(0.02)

    def close(self) -> None:
        try:  # a shared broker keeps retained messages: clear this run's status (empty payload)
            self.client.publish(f"{self.topic}/status", b"", qos=1, retain=True).wait_for_publish(5)
        except (RuntimeError, ValueError):  # no longer connected: nothing to clear then
            pass
        finally:
            self.client.loop_stop()
            self.client.disconnect()
