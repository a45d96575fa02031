"""An output closed because its view or stream stopped says so: not "reconnecting" (MQTT) or
"bound" (ZeroMQ), which read as a broker gone away or a socket still serving."""

from __future__ import annotations

from tests.mqtt import clear_retained, free_port, unique_topic
from weldpool_core.outputs import CellInfo
from weldpool_core.outputs.mqtt import MqttOptions, MqttPublisher
from weldpool_core.outputs.zmq import Publisher


def test_a_closed_mqtt_output_reads_disconnected(mqtt_broker: tuple[str, int]) -> None:
    host, port = mqtt_broker
    topic = unique_topic("closed")
    publisher = MqttPublisher(MqttOptions(f"mqtt://{host}:{port}/{topic}"), CellInfo("t", 2))
    try:
        assert publisher.wait_for_subscriber(10)
        assert publisher.status().state == "connected"
    finally:
        publisher.close()
    assert publisher.status().state == "disconnected"
    clear_retained(host, port, f"{topic}/status")


def test_a_closed_zeromq_output_reads_closed() -> None:
    publisher = Publisher(f"tcp://127.0.0.1:{free_port()}")
    assert publisher.status().state == "bound"
    publisher.close()
    assert publisher.status().state == "closed"
