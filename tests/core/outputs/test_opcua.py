"""The OPC UA server, read by a real asyncua client over TCP: values, units, subscriptions,
health, read-only, security, the learned classes' variables, and a port in use or a bad URL
refused in one sentence."""

from __future__ import annotations

import asyncio
import datetime as dt
import logging
import math
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from asyncua import Client, ua

from tests.core.outputs.common import record
from tests.helpers import run_cli
from tests.mqtt import free_port
from weldpool_core.cell.outputs import CellInfo, Outputs, Reporter
from weldpool_core.cell.outputs.opcua import NAMESPACE, OpcUaOptions, OpcUaServer
from weldpool_core.cell.outputs.opcua_security import CERTIFICATE_FILE, KEY_FILE
from weldpool_core.errors import InvalidInputError
from weldpool_core.student.classes import LearnedClass

CLASSES = (LearnedClass("wire", "mask"), LearnedClass("torch", "points", ("tip", "nozzle")))
"""A student's learned classes (``served`` with ``indirect=True``; none by default)."""


@pytest.fixture
def served(request: pytest.FixtureRequest) -> Iterator[tuple[OpcUaServer, str]]:
    port = free_port()
    info = CellInfo("tiny", 2, 0.1, classes=getattr(request, "param", ()))
    server = OpcUaServer(OpcUaOptions(f"opc.tcp://127.0.0.1:{port}"), info)
    yield server, f"opc.tcp://127.0.0.1:{port}/weldpool/"
    server.close()


async def _node(client: Client, name: str = "") -> Any:
    """The node ``WeldPool.<name>`` (``WeldPool`` itself without a name)."""
    index = await client.get_namespace_index(NAMESPACE)
    return client.get_node(ua.NodeId(f"WeldPool.{name}" if name else "WeldPool", index))


async def _names(node: Any) -> list[str]:
    return [(await child.read_browse_name()).Name for child in await node.get_children()]


async def _wait_for_frame(client: Client, frame: int) -> None:
    counter = await _node(client, "FrameCounter")
    for _ in range(100):
        if await counter.read_value() == frame:
            return
        await asyncio.sleep(0.02)


def test_a_plc_reads_each_value_with_its_unit_description_and_capture_time(
    served: tuple[OpcUaServer, str],
) -> None:
    server, url = served
    sent = record(7, width_px=42.0, scaled=True)
    server.send(sent)

    async def read() -> dict[str, Any]:
        async with Client(url) as client:
            width = await _node(client, "Width")
            await _wait_for_frame(client, 7)
            unit = await (await _node(client, "Width.EngineeringUnits")).read_value()
            area_unit = await (await _node(client, "Area.EngineeringUnits")).read_value()
            value = await width.read_data_value()
            with pytest.raises(ua.UaStatusCodeError):  # read-only: a PLC cannot write
                await width.write_value(1.0)
            return {
                "width": value.Value.Value,
                "stamp": value.SourceTimestamp,
                "unit": (unit.UnitId, unit.DisplayName.Text),
                "area_unit": area_unit.DisplayName.Text,
                "description": (await width.read_description()).Text,
                "keypoints": await (await _node(client, "Keypoints")).read_value(),
                "healthy": await (await _node(client, "Healthy")).read_value(),
                "stability": await (await _node(client, "StabilityCV")).read_value(),
                "unstable": await (await _node(client, "Unstable")).read_value(),
                "status": await (await _node(client, "Status")).read_value(),
                "model": await (await _node(client, "Model")).read_value(),
                "children": await _names(await _node(client)),
            }

    got = asyncio.run(read())
    assert got["width"] == pytest.approx(4.2)  # mm: the run has a scale
    assert got["stability"] == pytest.approx(0.05) and got["unstable"] is False
    assert got["unit"] == (0x4D4D54, "mm")  # UNECE "MMT"
    assert got["area_unit"] == "mm²"
    assert "across the travel direction" in got["description"]
    stamp = got["stamp"].replace(tzinfo=dt.UTC).timestamp()
    assert stamp == pytest.approx(sent["captured_at"], abs=1e-3)
    assert got["keypoints"][:2] == [17.0, 20.0] and all(math.isnan(v) for v in got["keypoints"][2:])
    assert (got["healthy"], got["status"], got["model"]) == (True, "ok", "tiny")
    assert "Width" in got["children"] and "Classes" not in got["children"]  # a pool-only student


CLASS_VALUES = (
    "Classes.wire.AreaPx",
    "Classes.wire.CentroidX",
    "Classes.wire.CentroidY",
    "Classes.torch.tip.X",
    "Classes.torch.tip.Y",
    "Classes.torch.nozzle.X",
    "Classes.torch.nozzle.Y",
)


@pytest.mark.parametrize("served", [CLASSES], indirect=True, ids=["classes"])
def test_each_learned_class_has_typed_variables_that_follow_the_frames(
    served: tuple[OpcUaServer, str],
) -> None:
    """A folder ``Classes``, one object per class and per named point; each frame's geometry in
    Double variables with units, stamped with its capture time; what the frame lacks (a point
    not seen, the centroid of an empty mask) reads BadNoData."""
    server, url = served
    first = {
        "wire": {"area_px": 830.0, "centroid": [120.5, 64.0]},
        "torch": {"tip": [412.5, 96.0], "nozzle": None},
    }
    second = {
        "wire": {"area_px": 0.0, "centroid": None},
        "torch": {"tip": [10.0, 300.0], "nozzle": [7.0, 8.0]},
    }
    sent = [record(1) | {"classes": first}, record(2) | {"classes": second}]

    async def read() -> dict[str, Any]:
        found: dict[str, Any] = {}
        async with Client(url) as client:
            classes = await _node(client, "Classes")
            found["folder"] = await classes.read_type_definition()
            found["names"] = [
                await _names(await _node(client, n))
                for n in ("Classes", "Classes.torch", "Classes.torch.tip", "Classes.wire")
            ]
            found["types"] = {
                await (await _node(client, n)).read_data_type_as_variant_type()
                for n in CLASS_VALUES
            }
            found["units"] = [
                (await (await _node(client, f"{n}.EngineeringUnits")).read_value()).DisplayName.Text
                for n in ("Classes.wire.AreaPx", "Classes.torch.tip.Y")
            ]
            for frame, values in enumerate(sent, start=1):
                server.send(values)
                await _wait_for_frame(client, frame)
                found[frame] = {
                    n: await (await _node(client, n)).read_attribute(
                        ua.AttributeIds.Value, raise_on_bad_status=False
                    )
                    for n in CLASS_VALUES
                }
        return found

    found = asyncio.run(read())
    assert found["folder"] == ua.NodeId(ua.ObjectIds.FolderType)
    assert found["names"] == [
        ["wire", "torch"],
        ["tip", "nozzle"],
        ["X", "Y"],
        ["AreaPx", "CentroidX", "CentroidY"],
    ]
    assert found["types"] == {ua.VariantType.Double} and found["units"] == ["px²", "px"]

    def values(frame: int) -> list[float]:
        return [
            v.Value.Value if v.StatusCode.is_good() else v.StatusCode.value
            for v in found[frame].values()
        ]

    no_data = ua.StatusCodes.BadNoData
    assert values(1) == [830.0, 120.5, 64.0, 412.5, 96.0, no_data, no_data]
    assert values(2) == [0.0, no_data, no_data, 10.0, 300.0, 7.0, 8.0]
    stamp = found[2]["Classes.torch.tip.X"].SourceTimestamp.replace(tzinfo=dt.UTC).timestamp()
    assert stamp == pytest.approx(sent[1]["captured_at"], abs=1e-3)  # the frame's capture time


def test_a_subscriber_sees_the_newest_frame_and_is_counted(served: tuple[OpcUaServer, str]) -> None:
    server, url = served
    seen: list[int] = []

    class Handler:
        def datachange_notification(self, _node: Any, value: Any, _data: Any) -> None:
            seen.append(int(value))

    async def watch() -> tuple[int, int]:
        async with Client(url) as client:
            subscription = await client.create_subscription(10, Handler())
            empty = server.status().subscribers  # created, watching nothing yet
            await subscription.subscribe_data_change(await _node(client, "FrameCounter"))
            counted = server.status().subscribers
            assert empty == 0, "a stream waiting for its subscriber would start too soon"
            feeder = threading.Thread(
                target=lambda: [(server.send(record(i)), time.sleep(0.002)) for i in range(1, 60)]
            )
            feeder.start()
            while feeder.is_alive() or (seen and seen[-1] != 59):
                await asyncio.sleep(0.02)
                if len(seen) > 1000:
                    break
            await subscription.delete()
            return counted or 0, server.status().subscribers or 0

    counted, after = asyncio.run(watch())
    assert counted == 1 and after == 0
    assert seen[-1] == 59 and seen == sorted(seen)  # in order; skipped frames allowed, never late
    status = server.status()
    assert status.sent + status.skipped == 59 and status.added_p99_ms is not None


@pytest.mark.parametrize("served", [CLASSES], indirect=True, ids=["classes"])
def test_no_frame_for_a_while_turns_healthy_off_and_marks_values_uncertain(
    served: tuple[OpcUaServer, str],
) -> None:
    """The pool's values and the learned classes' turn UncertainLastUsableValue."""
    server, url = served
    outputs = Outputs([server], CellInfo("tiny", 2, 0.1, stale_ms=300))
    geometry = {"torch": {"tip": [412.5, 96.0], "nozzle": None}}
    outputs.send(record(1, scaled=True) | {"classes": geometry})

    async def states() -> list[tuple[bool, str, int, int]]:
        found = []
        async with Client(url) as client:
            healthy, status = await _node(client, "Healthy"), await _node(client, "Status")
            width, tip = await _node(client, "Width"), await _node(client, "Classes.torch.tip.X")

            async def state() -> tuple[bool, str, int, int]:
                codes = [
                    (await node.read_attribute(ua.AttributeIds.Value, raise_on_bad_status=False))
                    for node in (width, tip)
                ]
                return (
                    await healthy.read_value(),
                    await status.read_value(),
                    codes[0].StatusCode.value,
                    codes[1].StatusCode.value,
                )

            for _ in range(2):
                await asyncio.sleep(0.7)
                found.append(await state())
                outputs.send(record(2, scaled=True) | {"classes": geometry})
                await asyncio.sleep(0.05)
                found.append(await state())
        return found

    found = asyncio.run(states())
    outputs._stop.set()
    uncertain, good = ua.StatusCodes.UncertainLastUsableValue, ua.StatusCodes.Good
    assert found[0][0] is False and found[0][1].startswith("no frame for")
    assert found[0][2:] == (uncertain, uncertain)
    assert found[1] == (True, "ok", good, good)  # the next frame makes it healthy again
    assert found[2][0] is False  # and a second pause is told again


def test_a_port_in_use_or_a_bad_address_is_one_sentence(served: tuple[OpcUaServer, str]) -> None:
    server, _url = served
    with pytest.raises(InvalidInputError, match="the port is in use; choose another port"):
        OpcUaServer(OpcUaOptions(f"opc.tcp://127.0.0.1:{server.port}"), CellInfo("m", 2))
    with pytest.raises(InvalidInputError, match="not an OPC UA endpoint"):
        OpcUaServer(OpcUaOptions("http://127.0.0.1:4840"), CellInfo("m", 2))
    with pytest.raises(InvalidInputError, match="needs the server's --opcua-cert"):
        OpcUaServer(OpcUaOptions("opc.tcp://127.0.0.1:1", "sign-encrypt"), CellInfo("m", 2))


def _client_certificate(folder: Path, name: str) -> tuple[Path, Path]:
    from asyncua.crypto.cert_gen import setup_self_signed_certificate
    from cryptography.x509.oid import ExtendedKeyUsageOID

    folder.mkdir(exist_ok=True)  # a trust folder holds certificates only: the key goes beside it
    key, cert = folder.with_name(f"{name}-key.pem"), folder / f"{name}.der"
    uri, use = f"urn:weldpool:test:{name}", [ExtendedKeyUsageOID.CLIENT_AUTH]
    asyncio.run(
        setup_self_signed_certificate(
            key, cert, uri, socket.gethostname(), use, {"organizationName": "weldpool"}
        )
    )
    return cert, key


def _read_securely(url: str, name: str, cert: Path, key: Path, server_cert: Path) -> float:
    from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

    async def read() -> float:
        client = Client(url)
        client.application_uri = f"urn:weldpool:test:{name}"
        await client.set_security(
            SecurityPolicyBasic256Sha256, str(cert), str(key), server_certificate=str(server_cert)
        )
        async with client:
            return float(await (await _node(client, "Width")).read_value())

    return asyncio.run(read())


def test_sign_and_encrypt_lets_in_only_clients_with_a_trusted_certificate(tmp_path: Path) -> None:
    """The server's certificate from `weldpool opcua-certificate`; a client without security is
    refused; with --opcua-trust, only a client whose certificate is in the folder gets in."""
    done = run_cli("opcua-certificate", str(tmp_path), "--host", socket.gethostname())
    assert done.returncode == 0, done.stderr
    server_cert, server_key = tmp_path / CERTIFICATE_FILE, tmp_path / KEY_FILE
    assert done.stdout.strip() == f"--opcua-cert {server_cert} --opcua-key {server_key}"
    again = run_cli("opcua-certificate", str(tmp_path))
    assert again.returncode == 2 and "exists already" in again.stderr
    trusted = _client_certificate(tmp_path / "clients", "plc")
    stranger = _client_certificate(tmp_path / "others", "laptop")
    port = free_port()
    options = OpcUaOptions(
        f"opc.tcp://127.0.0.1:{port}", "sign-encrypt", server_cert, server_key, tmp_path / "clients"
    )
    server = OpcUaServer(options, CellInfo("tiny", 2))
    url = f"opc.tcp://127.0.0.1:{port}/weldpool/"
    server.send(record(3))

    async def plain() -> None:
        async with Client(url) as client:
            await (await _node(client, "Width")).read_value()

    try:
        with pytest.raises(ua.UaError):  # no security: no endpoint for it
            asyncio.run(plain())
        assert _read_securely(url, "plc", *trusted, server_cert) == 50.0
        with pytest.raises(ua.UaError):  # a certificate the folder does not hold
            _read_securely(url, "laptop", *stranger, server_cert)
    finally:
        server.close()


def test_a_frame_without_a_pool_says_no_data_rather_than_a_good_nan(
    served: tuple[OpcUaServer, str],
) -> None:
    server, url = served
    empty = record(4, scaled=True) | {"width_px": None, "width_mm": None, "centroid": None}
    server.send(empty)

    async def read() -> tuple[Any, Any]:
        async with Client(url) as client:
            await _wait_for_frame(client, 4)
            width = await (await _node(client, "Width")).read_attribute(
                ua.AttributeIds.Value, raise_on_bad_status=False
            )
            length = await (await _node(client, "Length")).read_data_value()
            return width.StatusCode, length.StatusCode

    width, length = asyncio.run(read())
    assert width.value == ua.StatusCodes.BadNoData and length.is_good()


def test_flooding_clients_never_stop_the_frames(served: tuple[OpcUaServer, str]) -> None:
    """Three clients reading as fast as the server answers: every send returns, and the newest
    frame still reaches the address space."""
    server, url = served
    stop = threading.Event()

    async def flood() -> None:
        async with Client(url) as client:
            node = await _node(client, "Width")
            while not stop.is_set():
                await asyncio.gather(
                    *(
                        node.read_attribute(ua.AttributeIds.Value, raise_on_bad_status=False)
                        for _ in range(8)
                    )
                )

    flooders = [threading.Thread(target=lambda: asyncio.run(flood())) for _ in range(3)]
    for flooder in flooders:
        flooder.start()
    time.sleep(0.5)
    for frame in range(1, 400):
        server.send(record(frame, scaled=True))
    for _ in range(200):
        if server._last is not None and server._last.frame == 399:
            break
        time.sleep(0.02)
    stop.set()
    for flooder in flooders:
        flooder.join(timeout=10)
    status = server.status()
    assert server._last is not None and server._last.frame == 399
    assert status.sent + status.skipped == 399


def test_a_problem_is_logged_once_when_it_starts_and_once_when_it_ends(
    caplog: pytest.LogCaptureFixture,
) -> None:
    reporter = Reporter("MQTT mqtt://broker/t")
    with caplog.at_level(logging.WARNING, logger="weldpool.outputs"):
        for _ in range(50):
            reporter.problem("down", "the broker went away")
        reporter.resolved("down", "back")
        reporter.resolved("down", "back")
        reporter.problem("down", "the broker went away")
    assert [r.getMessage() for r in caplog.records] == [
        "MQTT mqtt://broker/t: the broker went away",
        "MQTT mqtt://broker/t: back",
        "MQTT mqtt://broker/t: the broker went away",
    ]
