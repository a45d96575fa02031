"""The ZeroMQ output counts its subscribers and never waits for one that stopped reading."""

from __future__ import annotations

import time

import zmq

from tests.core.outputs.common import record
from tests.mqtt import free_port
from weldpool_core.cell.outputs.zmq import Publisher


def test_subscribers_are_counted_as_they_come_and_go() -> None:
    address = f"tcp://127.0.0.1:{free_port()}"
    publisher = Publisher(address)
    context = zmq.Context()
    subscribers = []
    try:
        for _ in range(2):
            socket = context.socket(zmq.SUB)
            socket.setsockopt(zmq.SUBSCRIBE, b"")
            socket.connect(address)
            subscribers.append(socket)
        assert publisher.wait_for_subscriber(10)
        deadline = time.monotonic() + 10
        while publisher.status().subscribers != 2 and time.monotonic() < deadline:
            publisher.send(record(0))  # the count is read where the socket is used
            time.sleep(0.02)
        assert publisher.status().subscribers == 2
        subscribers.pop().close()
        while publisher.status().subscribers != 1 and time.monotonic() < deadline:
            publisher.send(record(1))
            time.sleep(0.02)
        assert publisher.status().subscribers == 1
    finally:
        for socket in subscribers:
            socket.close()
        publisher.close()
        context.term()


def test_a_subscriber_that_stops_reading_never_blocks_a_frame() -> None:
    address = f"tcp://127.0.0.1:{free_port()}"
    publisher = Publisher(address)
    context = zmq.Context()
    idle = context.socket(zmq.SUB)
    idle.setsockopt(zmq.RCVHWM, 10)
    idle.setsockopt(zmq.SUBSCRIBE, b"")
    idle.connect(address)
    try:
        assert publisher.wait_for_subscriber(10)
        for frame in range(20_000):  # far beyond both high-water marks: dropped, not queued
            publisher.send(record(frame))
        assert publisher.status().sent == 20_000
    finally:
        idle.close()
        publisher.close()
        context.term()
