"""Where the stream's records go in a welding cell: ZeroMQ, OPC UA and MQTT, one module each,
opened from one registry (``OUTPUTS``).

Every output takes each record with ``send`` and never blocks the inference thread: the OPC UA
server and the MQTT client run on threads of their own and take the newest record when they are
ready (a slow network or a flooding client makes them skip frames, never delay the next one).
``status()`` says what a live view shows: the state, the subscriber count where the protocol
knows it, frames sent and skipped, and the time ``send`` → on the wire (``added_ms``).
``base`` holds the terms they share (``CellRecord``, the one rule for what the cell reads),
``fanout`` the outputs together (``Outputs``).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from weldpool_core.cell.outputs.base import (
    CELL_FIELDS,
    KEEP_LATENCIES,
    STALE_MS,
    CellField,
    CellInfo,
    CellRecord,
    Counters,
    Output,
    OutputStatus,
    Reporter,
)
from weldpool_core.cell.outputs.fanout import Outputs

__all__ = [
    "CELL_FIELDS",
    "KEEP_LATENCIES",
    "OUTPUTS",
    "STALE_MS",
    "CellField",
    "CellInfo",
    "CellRecord",
    "Counters",
    "Output",
    "OutputStatus",
    "Outputs",
    "OutputsConfig",
    "Reporter",
    "open_outputs",
]


@dataclass(frozen=True)
class OutputsConfig:
    """Which outputs a stream opens (``weldpool stream`` options, the live view's form): each
    field is the registry's name of an output and its options (None: not opened)."""

    zeromq: str | None = None
    """The address to bind."""
    opcua: Any = None
    """``opcua.OpcUaOptions`` or None."""
    mqtt: Any = None
    """``mqtt.MqttOptions`` or None."""

    def any(self) -> bool:
        return any(getattr(self, name) for name in OUTPUTS)


OUTPUTS: dict[str, tuple[str, str]] = {
    "zeromq": ("weldpool_core.cell.outputs.zmq", "open_output"),
    "opcua": ("weldpool_core.cell.outputs.opcua", "open_output"),
    "mqtt": ("weldpool_core.cell.outputs.mqtt", "open_output"),
}
"""Each output: its ``OutputsConfig`` field, and the module and function that open it from its
options and the run's ``CellInfo`` (a module is imported only when its output is asked for)."""


def _opener(name: str) -> Callable[[Any, CellInfo], Output]:
    module, function = OUTPUTS[name]
    opener: Callable[[Any, CellInfo], Output] = getattr(importlib.import_module(module), function)
    return opener


def open_outputs(config: OutputsConfig, info: CellInfo) -> Outputs:
    """Open each configured output, in the registry's order (one-sentence ``InvalidInputError``
    for a bad address, a port in use or a broker host that does not resolve); what opened is
    closed again on a failure."""
    opened: list[Any] = []
    try:
        for name in OUTPUTS:
            options = getattr(config, name)
            if options is not None and options != "":
                opened.append(_opener(name)(options, info))
    except BaseException:
        Outputs(opened, info).close()  # each closed, even when one of them fails to
        raise
    return Outputs(opened, info)
