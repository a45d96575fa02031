"""MQTT against a real mosquitto: one message per frame, the rate limit, the status topic and a
broker that goes away and comes back while frames keep coming."""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
import pytest

from tests.core.outputs.common import record
from tests.mqtt import Listener, start_broker, unique_topic
from weldpool_core.cell.outputs import CellInfo, OutputsConfig, open_outputs
from weldpool_core.cell.outputs.mqtt import MqttOptions, MqttPublisher, parse_mqtt_url
from weldpool_core.errors import InvalidInputError


@pytest.fixture
def listener(mqtt_broker: tuple[str, int], request: pytest.FixtureRequest) -> Iterator[Listener]:
    found = Listener(*mqtt_broker, unique_topic(request.node.name[:40]))
    yield found
    found.close()


def test_every_frame_is_one_compact_message_and_the_status_is_retained(
    listener: Listener,
) -> None:
    topic = listener.topic
    publisher = MqttPublisher(MqttOptions(listener.url, qos=1), CellInfo("tiny", 2, 0.1))
    assert publisher.wait_for_subscriber(10)
    for frame in range(20):
        publisher.send(record(frame, width_px=40.0 + frame, scaled=True))
    listener.wait_for(lambda: len(listener.frames(topic)) == 20)
    publisher.close()
    listener.wait_for(
        lambda: (
            listener.frames(f"{topic}/status")[-1:] != []
            and listener.frames(f"{topic}/status")[-1]["state"] == "offline"
        )
    )
    frames = listener.frames(topic)
    assert [m["frame"] for m in frames] == list(range(20))
    assert frames[5]["width"] == pytest.approx(4.5) and frames[5]["keypoints"][1] is None
    states = [m["state"] for m in listener.frames(f"{topic}/status")]
    assert states[0] == "online" and states[-1] == "offline"
    status = publisher.status()
    assert (status.sent, status.skipped, status.subscribers) == (20, 0, None)


def test_a_rate_sends_the_newest_frame_at_most_that_often(
    listener: Listener,
) -> None:
    topic = listener.topic
    publisher = MqttPublisher(MqttOptions(listener.url, rate_hz=5), CellInfo("t", 2))
    assert publisher.wait_for_subscriber(10)
    started = time.monotonic()
    for frame in range(100):  # 100 frames in about 1 s
        publisher.send(record(frame))
        time.sleep(0.01)
    elapsed = time.monotonic() - started
    publisher.close()  # sends the last pending frame
    listener.wait_for(lambda: [m["frame"] for m in listener.frames(topic)][-1:] == [99])
    frames = [m["frame"] for m in listener.frames(topic)]
    assert 1 <= len(frames) <= 5 * elapsed + 2  # about 5 a second, not 100
    assert frames == sorted(frames) and frames[-1] == 99  # the newest frame each time, and the last


def test_a_broker_that_goes_away_never_stops_the_frames_and_is_told_once(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    process, port = start_broker(tmp_path)
    publisher = MqttPublisher(MqttOptions(f"mqtt://127.0.0.1:{port}/cell/away"), CellInfo("t", 2))
    try:
        assert publisher.wait_for_subscriber(10)
        with caplog.at_level(logging.WARNING, logger="weldpool.outputs"):
            process.terminate()
            process.wait(timeout=10)
            for _ in range(100):
                if publisher.status().state == "reconnecting":
                    break
                time.sleep(0.05)
            for frame in range(300):  # the stream goes on: every send returns
                publisher.send(record(frame))
            assert publisher.status().skipped >= 300 - 5
            process, _ = start_broker(tmp_path, port)
            listener = Listener("127.0.0.1", port, "cell/away")
            for _ in range(400):  # paho's back-off starts at 1 s
                if publisher.status().state == "connected":
                    break
                time.sleep(0.05)
            publisher.send(record(500))
            listener.wait_for(lambda: listener.frames("cell/away") != [])
            listener.close()
        lines = [r.getMessage() for r in caplog.records]
        assert len([line for line in lines if "went away" in line]) == 1
        assert len([line for line in lines if "is back" in line]) == 1
        assert [m["frame"] for m in listener.frames("cell/away")] == [500]
    finally:
        publisher.close()
        process.terminate()
        process.wait(timeout=10)


def test_bad_addresses_are_one_sentence() -> None:
    for url, words in (
        ("http://broker/topic", "not an MQTT address"),
        ("mqtt://broker", "needs a topic"),
        ("mqtt://broker/cell/#", "needs a topic without wildcards"),
        ("mqtt://broker:99999/t", "not a number from 1 to 65535"),
    ):
        with pytest.raises(InvalidInputError, match=words):
            parse_mqtt_url(url)
    with pytest.raises(InvalidInputError, match="does not resolve"):
        open_outputs(
            OutputsConfig(mqtt=MqttOptions("mqtt://no-such-broker.invalid/t")), CellInfo("t", 2)
        )
    assert parse_mqtt_url("mqtts://u:p%40ss@b/x/y").password == "p@ss"
    assert parse_mqtt_url("mqtts://b/x").port == 8883


def _tls_files(folder: Path) -> tuple[Path, Path, Path]:
    """A CA, and a certificate for 127.0.0.1 signed by it, with its key."""
    import datetime as dt
    import ipaddress

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import rsa
    from cryptography.x509.oid import NameOID

    def name(text: str) -> x509.Name:
        return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, text)])

    now = dt.datetime.now(dt.UTC)
    ca_key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    ca = (
        x509.CertificateBuilder()
        .subject_name(name("weldpool test CA"))
        .issuer_name(name("weldpool test CA"))
        .public_key(ca_key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - dt.timedelta(minutes=5))
        .not_valid_after(now + dt.timedelta(days=1))
        .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
        .sign(ca_key, hashes.SHA256())
    )
    key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    address = x509.IPAddress(ipaddress.ip_address("127.0.0.1"))
    cert = (
        x509.CertificateBuilder()
        .subject_name(name("127.0.0.1"))
        .issuer_name(ca.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - dt.timedelta(minutes=5))
        .not_valid_after(now + dt.timedelta(days=1))
        .add_extension(x509.SubjectAlternativeName([address]), critical=False)
        .sign(ca_key, hashes.SHA256())
    )
    paths = folder / "ca.pem", folder / "broker.pem", folder / "broker-key.pem"
    paths[0].write_bytes(ca.public_bytes(serialization.Encoding.PEM))
    paths[1].write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    paths[2].write_bytes(
        key.private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.TraditionalOpenSSL,
            serialization.NoEncryption(),
        )
    )
    return paths


def test_tls_and_credentials_reach_a_broker_that_needs_both(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    import subprocess

    ca, cert, key = _tls_files(tmp_path)
    passwords = tmp_path / "passwords"
    subprocess.run(["mosquitto_passwd", "-b", "-c", str(passwords), "weld", "s3cret"], check=True)
    settings = (
        f"cafile {ca}\ncertfile {cert}\nkeyfile {key}\n"
        f"allow_anonymous false\npassword_file {passwords}\n"
    )
    process, port = start_broker(tmp_path, settings=settings)
    url = f"mqtts://weld@127.0.0.1:{port}/cell/tls"
    good = MqttPublisher(MqttOptions(url, password="s3cret", ca_file=ca), CellInfo("t", 2))
    with caplog.at_level(logging.WARNING, logger="weldpool.outputs"):
        wrong = MqttPublisher(MqttOptions(url, password="guess", ca_file=ca), CellInfo("t", 2))
        try:
            assert good.wait_for_subscriber(10)
            assert good.status().address == url
            got: list[Any] = []
            reader = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
            reader.username_pw_set("weld", "s3cret")
            reader.tls_set(ca_certs=str(ca))
            reader.on_message = lambda _c, _u, m: got.append(json.loads(m.payload))
            ready = threading.Event()
            reader.on_subscribe = lambda *_a: ready.set()
            reader.connect("127.0.0.1", port)
            reader.subscribe("cell/tls", 1)
            reader.loop_start()
            assert ready.wait(10)
            good.send(record(11))
            deadline = time.monotonic() + 10
            while not got and time.monotonic() < deadline:
                time.sleep(0.02)
            reader.loop_stop()
            reader.disconnect()
            assert [m["frame"] for m in got] == [11]
            assert not wrong.wait_for_subscriber(2)  # the broker refuses a wrong password
            assert wrong.status().state == "connecting"
        finally:
            good.close()
            wrong.close()
            process.terminate()
            process.wait(timeout=10)
    refusals = [
        r.getMessage() for r in caplog.records if "refused the connection" in r.getMessage()
    ]
    assert len(refusals) == 1  # told once, though paho retries


def test_the_status_says_stale_in_a_pause_and_online_when_frames_come_again(
    listener: Listener,
) -> None:
    topic = listener.topic
    info = CellInfo("t", 2, stale_ms=200)
    outputs = open_outputs(OutputsConfig(mqtt=MqttOptions(listener.url)), info)
    try:
        assert outputs.outputs[0].wait_for_subscriber(10)
        time.sleep(0.5)  # no frame yet: the watchdog is armed by the first one, not the opening
        outputs.send(record(1))
        time.sleep(0.6)  # a pause
        outputs.send(record(2))
        listener.wait_for(lambda: len(listener.frames(f"{topic}/status")) >= 3)
    finally:
        outputs.close()
    states = [m["state"] for m in listener.frames(f"{topic}/status")]
    assert states[:3] == ["online", "stale", "online"]


def test_frames_reach_the_broker_from_a_process_holding_over_1023_files(
    mqtt_broker: tuple[str, int],
) -> None:
    """paho's loop waits with ``select``, which refuses a descriptor of 1024 or more: in a
    server holding that many files every connection was lost at once, silently. With
    ``poll_paho`` the publisher (and the listener) connect and every frame arrives."""
    held = [open("/dev/null") for _ in range(1100)]  # noqa: SIM115 (held open on purpose)
    try:
        listener = Listener(*mqtt_broker, unique_topic("many-files"))
        publisher = MqttPublisher(MqttOptions(listener.url, qos=1), CellInfo("tiny", 2, 0.1))
        assert publisher.wait_for_subscriber(10)
        for frame in range(5):
            publisher.send(record(frame))
        listener.wait_for(lambda: len(listener.frames(listener.topic)) == 5)
        assert [f["frame"] for f in listener.frames(listener.topic)] == list(range(5))
        publisher.close()
        listener.close()
    finally:
        for handle in held:
            handle.close()
