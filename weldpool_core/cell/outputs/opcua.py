"""An OPC UA server for PLCs and robot controllers (asyncua): one variable per ``CELL_FIELDS``.

The address space (namespace ``urn:weldpool:stream``) holds one object, ``WeldPool``, under
Objects; each value is a variable with a string node id ``ns=<i>;s=WeldPool.<Name>`` (e.g.
``WeldPool.Width``), its description and ``EngineeringUnits`` (UNECE codes: mm, mm², ms, s;
pixels have no UNECE code and say "px"), plus ``Status`` (a sentence) and ``Model``. All are
read-only. Each value carries the frame's capture time as its source timestamp. When no frame
comes for ``stale_ms``, ``Healthy`` turns False and the measurements keep their last value with
the status code ``UncertainLastUsableValue``.

The server runs its own asyncio loop on a thread. ``send`` only keeps the newest record and
wakes the loop; the loop writes the newest record it finds, so a busy server skips frames
(``skipped``) instead of queueing them, and the inference thread never waits for a client.
Security (``opcua_security``): ``none`` (a lab bench) or ``sign-encrypt`` (Basic256Sha256 with
the server's certificate and private key; clients must present certificates, which
``trust_dir`` limits to the ones found there). The learned classes' variables sit under
``WeldPool.Classes`` (``opcua_classes``).
"""

from __future__ import annotations

import asyncio
import contextlib
import datetime as dt
import errno
import logging
import math
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import urlparse

from weldpool_core.cell.outputs.base import (
    CELL_FIELDS,
    CellInfo,
    CellRecord,
    Counters,
    OutputStatus,
    Reporter,
)
from weldpool_core.cell.outputs.opcua_classes import ClassVariable, class_layout
from weldpool_core.cell.outputs.opcua_security import APPLICATION_URI, secure
from weldpool_core.errors import InvalidInputError

NAMESPACE = "urn:weldpool:stream"
OBJECT = "WeldPool"
SECURITY = ("none", "sign-encrypt")
START_TIMEOUT_S = 20.0
CLOSE_LINGER_S = 0.5
"""At the end of a stream, subscribers get this long to receive the last values."""
BEHIND_WINDOW_S = 1.0
"""The server counts as behind when it skipped over half the frames of this window."""
MEASUREMENTS = (
    "Area",
    "Length",
    "Width",
    "CentroidX",
    "CentroidY",
    "Keypoints",
    "Uncertainty",
    "Ambiguity",
    "LatencyMs",
)
"""The values that turn ``UncertainLastUsableValue`` when frames stop."""
_UNECE = "http://www.opcfoundation.org/UA/units/un/cefact"
_UNITS = {"mm": "MMT", "mm²": "MMK", "ms": "C26", "s": "SEC"}


@dataclass(frozen=True)
class OpcUaOptions:
    """How the server listens and whom it lets in."""

    url: str
    security: str = "none"
    certificate: Path | None = None
    private_key: Path | None = None
    trust_dir: Path | None = None


def parse_opcua_url(url: str) -> tuple[str, int]:
    """Host and port of an ``opc.tcp://host:port[/path]`` endpoint (one-sentence errors)."""
    parsed = urlparse(url)
    if parsed.scheme != "opc.tcp" or not parsed.hostname:
        raise InvalidInputError(
            f"{url!r} is not an OPC UA endpoint; give opc.tcp://HOST:PORT, e.g. "
            "opc.tcp://0.0.0.0:4840."
        )
    try:
        port = parsed.port or 4840
    except ValueError:
        raise InvalidInputError(f"The port of {url!r} is not a number from 1 to 65535.") from None
    return parsed.hostname, port


def _ua() -> Any:
    """asyncua's ``ua`` module, imported when a server starts (its stubs type node ids and
    timestamps more narrowly than the library takes them)."""
    from asyncua import ua

    return ua


def _unit(text: str) -> Any:
    ua = _ua()
    code = _UNITS.get(text)
    if code is None:
        return ua.EUInformation(
            NamespaceUri="urn:weldpool:units",
            UnitId=-1,
            DisplayName=ua.LocalizedText(text or "-"),
            Description=ua.LocalizedText("pixel" if text.startswith("px") else "dimensionless"),
        )
    unit_id = (ord(code[0]) << 16) | (ord(code[1]) << 8) | ord(code[2])
    return ua.EUInformation(
        NamespaceUri=_UNECE,
        UnitId=unit_id,
        DisplayName=ua.LocalizedText(text),
        Description=ua.LocalizedText(text),
    )


class OpcUaServer:
    """The stream's values as OPC UA variables (see the module doc)."""

    kind = "opcua"

    def __init__(self, options: OpcUaOptions, info: CellInfo) -> None:
        self.host, self.port = parse_opcua_url(options.url)
        if options.security not in SECURITY:
            raise InvalidInputError(
                f"--opcua-security must be one of {', '.join(SECURITY)}, not {options.security!r}."
            )
        if options.security == "sign-encrypt" and not (options.certificate and options.private_key):
            raise InvalidInputError(
                "--opcua-security sign-encrypt needs the server's --opcua-cert and --opcua-key."
            )
        for path in (options.certificate, options.private_key, options.trust_dir):
            if path is not None and not path.exists():
                raise InvalidInputError(f"There is no file or folder {str(path)!r} for OPC UA.")
        self.address = options.url
        self.options = options
        self.info = info
        self.counters = Counters()
        self.reporter = Reporter(f"OPC UA {options.url}")
        library_log = logging.getLogger("asyncua")
        if library_log.level == logging.NOTSET:  # its chatter and tracebacks are not for the
            library_log.setLevel(logging.CRITICAL)  # cell: what matters is told by ``reporter``
        self._latest: tuple[dict[str, Any], float] | None = None
        self._lock = threading.Lock()
        self._wake: asyncio.Event | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._started = threading.Event()
        self._error: BaseException | None = None
        self._nodes: dict[str, Any] = {}
        self._class_nodes: list[tuple[Any, ClassVariable]] = []
        self._server: Any = None
        self._stop_event: asyncio.Event | None = None
        self._abandoned = False
        self._last: CellRecord | None = None
        self._window: list[int] = [0, 0]  # frames sent, skipped in the current window
        self._window_start = time.perf_counter()
        self._thread = threading.Thread(target=self._run, name="opcua-server", daemon=True)
        self._thread.start()
        if not self._started.wait(START_TIMEOUT_S):
            self._abandoned = True  # it stops as soon as it starts, if it ever does
            self.close()
            raise InvalidInputError(f"The OPC UA server on {options.url!r} did not start in time.")
        if self._error is not None:
            self._thread.join(timeout=5)
            raise self._error

    # The inference thread's side.
    def send(self, record: dict[str, Any]) -> None:
        with self._lock:
            if self._latest is not None:
                self.counters.skipped += 1
                self._window[1] += 1
            self._latest = (record, time.perf_counter())
        loop, wake = self._loop, self._wake
        if loop is not None and wake is not None and not wake.is_set():
            with contextlib.suppress(RuntimeError):  # the loop ended meanwhile (reported there)
                loop.call_soon_threadsafe(wake.set)

    def stale(self, quiet_ms: float) -> None:
        loop = self._loop
        if loop is not None:
            with contextlib.suppress(RuntimeError):
                asyncio.run_coroutine_threadsafe(self._write_stale(quiet_ms), loop)

    def subscriptions(self) -> int:
        """Clients' subscriptions on this server that watch at least one variable (what a PLC
        opens to be told of changes). A subscription is created empty and its variables added
        by a second request: counting it before then would let a stream waiting for its
        subscriber start, and end, before the client had asked for any value."""
        server = self._server
        if server is None:
            return 0
        subscriptions = server.iserver.subscription_service.subscriptions.values()
        return sum(1 for s in subscriptions if _watched(s))

    def wait_for_subscriber(self, seconds: float) -> bool:
        """True once a client has subscribed; False after ``seconds`` without one."""
        deadline = time.perf_counter() + seconds
        while self.subscriptions() == 0:
            if time.perf_counter() >= deadline:
                return False
            time.sleep(0.02)
        return True

    def status(self) -> OutputStatus:
        p50, p99 = self.counters.percentiles()
        return OutputStatus(
            self.kind,
            self.address,
            "serving" if self._loop is not None else "stopped",
            self.subscriptions(),
            self.counters.sent,
            self.counters.skipped,
            p50,
            p99,
        )

    def close(self) -> None:
        loop = self._loop
        if loop is not None and self._stop_event is not None:
            loop.call_soon_threadsafe(self._stop_event.set)
        self._thread.join(timeout=10)

    # The server's thread.
    def _run(self) -> None:
        try:
            asyncio.run(self._serve())
        except BaseException as exc:  # reported to the opener, or logged when it ends later
            if not self._started.is_set():
                self._error = _start_error(exc, self.options.url)
                self._started.set()
            else:
                self.reporter.problem("crashed", f"the server stopped: {exc}")
        finally:
            self._loop = None

    async def _serve(self) -> None:
        from asyncua.server.server import Server

        self._stop_event = asyncio.Event()
        self._wake = asyncio.Event()
        server = Server()
        await server.init()
        server.set_endpoint(f"opc.tcp://{self.host}:{self.port}/weldpool/")
        server.set_server_name("weldpool stream")
        await server.set_application_uri(APPLICATION_URI)
        await secure(server, self.options, self.reporter)
        index = await server.register_namespace(NAMESPACE)
        await self._build(server, index)
        async with server:
            self._server = server
            self._loop = asyncio.get_running_loop()
            self._started.set()
            if self._abandoned:
                return
            writer = asyncio.create_task(self._write_loop())
            await self._stop_event.wait()
            writer.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await writer
            await self._write_latest()  # the last frame is not lost to the end of the stream
            await self._write_text("Status", "the stream has ended")
            await self._write_flag(False)
            if self.subscriptions():  # subscribers get the last values before the server goes
                await asyncio.sleep(CLOSE_LINGER_S)
        self._loop = None

    async def _build(self, server: Any, index: int) -> None:
        """The ``WeldPool`` object, its variables, and the learned classes' (``_build_classes``)."""
        ua = _ua()
        pool = await server.nodes.objects.add_object(ua.NodeId(OBJECT, index), f"{index}:{OBJECT}")
        await _describe(pool, "The weld pool as the student sees it.")
        initial: dict[str, tuple[Any, Any]] = {
            "FrameCounter": (0, ua.VariantType.UInt64),
            "CaptureTime": (dt.datetime.now(dt.UTC), ua.VariantType.DateTime),
            "Keypoints": ([math.nan] * (2 * self.info.keypoints), ua.VariantType.Double),
            "Healthy": (False, ua.VariantType.Boolean),
            "Unstable": (False, ua.VariantType.Boolean),
        }
        for spec in CELL_FIELDS:
            value, variant = initial.get(spec.name, (math.nan, ua.VariantType.Double))
            unit = "" if spec.name == "CaptureTime" else self.info.unit(spec)
            node = await _add_value(
                pool, index, (spec.name,), value, variant, spec.description, unit
            )
            self._nodes[spec.name] = node.nodeid
        for name, text, description in (
            ("Status", "waiting for the first frame", "Why the stream is or is not healthy."),
            ("Model", self.info.model, "The student that makes the values."),
        ):
            string = ua.VariantType.String
            node = await _add_value(pool, index, (name,), text, string, description, "")
            self._nodes[name] = node.nodeid
        await self._build_classes(pool, index)

    async def _build_classes(self, pool: Any, index: int) -> None:
        """The learned classes' folder, objects and variables (``opcua_classes``)."""
        ua = _ua()
        objects, variables = class_layout(self.info.classes)
        parents: dict[tuple[str, ...], Any] = {(): pool}
        for item in objects:
            parent, name = parents[item.path[:-1]], item.path[-1]
            node_id, browse = ua.NodeId(_node_id(item.path), index), ua.QualifiedName(name, index)
            if len(item.path) == 1:
                node = await parent.add_folder(node_id, browse)
            else:
                node = await parent.add_object(node_id, browse)
            await _describe(node, item.description)
            parents[item.path] = node
        for variable in variables:
            parent = parents[variable.path[:-1]]
            node = await _add_value(
                parent,
                index,
                variable.path,
                math.nan,
                ua.VariantType.Double,
                variable.description,
                variable.unit,
            )
            self._class_nodes.append((node.nodeid, variable))

    async def _write_loop(self) -> None:
        assert self._wake is not None
        while True:
            await self._wake.wait()
            self._wake.clear()
            await self._write_latest()

    async def _write_latest(self) -> None:
        """Write the newest record ``send`` left, if any (older ones were skipped)."""
        with self._lock:
            latest, self._latest = self._latest, None
        if latest is None:
            return
        record, since = latest
        try:
            await self._write_record(CellRecord.of(record, self.info))
        except Exception as exc:  # a bad record must not stop the values for good
            self.reporter.problem("write", f"a frame could not be written ({exc!r})")
            return
        self.reporter.resolved("write", "frames are written again")
        self.counters.added(since)
        self._window[0] += 1
        self._check_behind()

    async def _write_record(self, cell: CellRecord) -> None:
        ua = _ua()
        stamp = dt.datetime.fromtimestamp(cell.t, dt.UTC)
        now = dt.datetime.now(dt.UTC)
        values: dict[str, tuple[Any, Any]] = {
            "FrameCounter": (cell.frame, ua.VariantType.UInt64),
            "CaptureTime": (stamp, ua.VariantType.DateTime),
            "Keypoints": (list(cell.keypoints), ua.VariantType.Double),
            "Healthy": (cell.healthy, ua.VariantType.Boolean),
            "Unstable": (cell.unstable, ua.VariantType.Boolean),
        }
        good, none = ua.StatusCode(ua.StatusCodes.Good), ua.StatusCode(ua.StatusCodes.BadNoData)
        writes: list[tuple[Any, Any, Any]] = []
        for spec in CELL_FIELDS:
            value, variant = values.get(spec.name, (None, ua.VariantType.Double))
            if value is None:
                value = getattr(cell, spec.key)
            writes.append((self._nodes[spec.name], value, variant))
        for node, variable in self._class_nodes:
            writes.append((node, variable.value(cell.classes), ua.VariantType.Double))
        # One frame's values in one run of writes that never yields to the loop: a client's
        # read, served by the same loop, sees all of a frame or none of it.
        for node, value, variant in writes:
            missing = isinstance(value, float) and math.isnan(value)  # no pool, no samples
            await self._server.write_attribute_value(
                node,
                ua.DataValue(
                    ua.Variant(value, variant),
                    StatusCode=none if missing else good,
                    SourceTimestamp=stamp,
                    ServerTimestamp=now,
                ),
            )
        if self._last is None or not self._last.healthy or not cell.healthy:
            await self._write_text("Status", "ok" if cell.healthy else "the model is not usable")
        self._last = cell

    async def _write_stale(self, quiet_ms: float) -> None:
        ua = _ua()
        await self._write_flag(False)
        await self._write_text("Status", f"no frame for {quiet_ms:.0f} ms")
        self._last = None
        classes = [node for node, _variable in self._class_nodes]
        for node in [self._nodes[name] for name in MEASUREMENTS] + classes:
            current = self._server.read_attribute_value(node)
            if not current.StatusCode.is_good():  # no data stays no data
                continue
            await self._server.write_attribute_value(
                node,
                ua.DataValue(
                    current.Value,
                    StatusCode=ua.StatusCode(ua.StatusCodes.UncertainLastUsableValue),
                    SourceTimestamp=current.SourceTimestamp,
                    ServerTimestamp=dt.datetime.now(dt.UTC),
                ),
            )

    async def _write_flag(self, healthy: bool) -> None:
        ua = _ua()
        await self._server.write_attribute_value(
            self._nodes["Healthy"], ua.DataValue(ua.Variant(healthy, ua.VariantType.Boolean))
        )

    async def _write_text(self, name: str, text: str) -> None:
        ua = _ua()
        await self._server.write_attribute_value(
            self._nodes[name], ua.DataValue(ua.Variant(text, ua.VariantType.String))
        )

    def _check_behind(self) -> None:
        now = time.perf_counter()
        if now - self._window_start < BEHIND_WINDOW_S:
            return
        sent, skipped = self._window
        self._window, self._window_start = [0, 0], now
        if skipped > sent:
            self.reporter.problem(
                "behind",
                f"the server is behind ({skipped} of {sent + skipped} frames skipped in the last "
                "second): a client may be flooding it; values skip frames, inference goes on",
            )
        else:
            self.reporter.resolved("behind", "the server keeps up with the frames again")


def _node_id(path: tuple[str, ...]) -> str:
    """A variable's or object's string node id: its browse path under Objects, joined by dots."""
    return ".".join((OBJECT, *path))


async def _describe(node: Any, text: str) -> None:
    ua = _ua()
    await node.write_attribute(
        ua.AttributeIds.Description, ua.DataValue(ua.Variant(ua.LocalizedText(text)))
    )


async def _add_value(
    parent: Any,
    index: int,
    path: tuple[str, ...],
    value: Any,
    variant: Any,
    description: str,
    unit: str,
) -> Any:
    """A read-only variable at ``path`` with its description and, with a unit, its
    ``EngineeringUnits`` property."""
    ua = _ua()
    node_id = _node_id(path)
    node = await parent.add_variable(
        ua.NodeId(node_id, index), ua.QualifiedName(path[-1], index), value, variant
    )
    await _describe(node, description)
    if unit:
        await node.add_property(
            ua.NodeId(f"{node_id}.EngineeringUnits", index),
            "EngineeringUnits",
            _unit(unit),
            datatype=ua.NodeId(ua.ObjectIds.EUInformation),
        )
    return node


def _start_error(exc: BaseException, url: str) -> BaseException:
    """A start-up failure as one sentence (a port in use, an unknown host, a bad certificate)."""
    if isinstance(exc, InvalidInputError):
        return exc
    if isinstance(exc, OSError):
        if exc.errno == errno.EADDRINUSE:
            return InvalidInputError(
                f"Cannot serve OPC UA on {url!r}: the port is in use; choose another port."
            )
        return InvalidInputError(f"Cannot serve OPC UA on {url!r}: {exc.strerror or exc}.")
    return InvalidInputError(f"Cannot serve OPC UA on {url!r}: {exc}.")


def open_output(options: OpcUaOptions, info: CellInfo) -> OpcUaServer:
    """The OPC UA output of the registry (``weldpool_core.cell.outputs.OUTPUTS``)."""
    return OpcUaServer(options, info)


def _watched(subscription: Any) -> int:
    """How many variables an asyncua server subscription monitors (its monitored-item
    service keeps them in a dict asyncua exposes no accessor for)."""
    return len(getattr(subscription.monitored_item_srv, "_monitored_items", {}))
