"""Payloads of the live views."""

from __future__ import annotations

import datetime as dt
from typing import Any

from pydantic import BaseModel, Field

from app.core.bounds import MAX_MM_PER_PX, MIN_MM_PER_PX


class LiveIn(BaseModel):
    source: str = Field(
        min_length=1,
        max_length=500,
        description="A camera index on the server (0, 1, …), an RTSP/HTTP URL, or the path of a "
        "video file on the server (played at its own frame rate).",
    )
    model_id: int | None = Field(
        default=None, ge=1, le=2**31 - 1, description="A student version; null: the promoted one."
    )
    smooth: bool = Field(default=True, description="One-euro filter on the keypoint tracks.")
    sequential: bool = Field(
        default=False,
        description="Run the version's sequential cell (it keeps a state from frame to frame: "
        "a steadier mask and keypoints); the version must have one (`sequential` on the model).",
    )
    int8: bool = Field(
        default=False,
        description="Run the version's int8 student (faster on a CPU, its masks checked against "
        "the float student's); the version must have one (`int8` on the model). Not with "
        "`sequential`.",
    )
    mm_per_px: float | None = Field(default=None, ge=MIN_MM_PER_PX, le=MAX_MM_PER_PX)
    travel_deg: float | None = Field(default=None, ge=-360, le=360)
    zeromq: str | None = Field(
        default=None,
        max_length=200,
        description="Publish each record on ZeroMQ at this address, e.g. tcp://0.0.0.0:5556.",
    )
    opcua: str | None = Field(
        default=None,
        max_length=200,
        description="Serve the values over OPC UA (no security: a lab bench), e.g. "
        "opc.tcp://0.0.0.0:4840. For certificates, run `weldpool stream --opcua-security`.",
    )
    mqtt: str | None = Field(
        default=None,
        max_length=500,
        description="Publish one JSON message per frame, e.g. mqtt://broker:1883/cell1/pool.",
    )


class LiveOutputOut(BaseModel):
    kind: str = Field(description="zeromq, opcua or mqtt.")
    address: str
    state: str = Field(
        description="bound, serving, connecting, connected, reconnecting; once the view ended: "
        "closed (ZeroMQ), stopped (OPC UA), disconnected (MQTT)."
    )
    subscribers: int | None = Field(
        description="ZeroMQ subscribers, OPC UA subscriptions; null for MQTT (the broker knows)."
    )
    sent: int
    skipped: int = Field(description="Frames not sent: the broker away, or a busy server.")
    added_p99_ms: float | None = Field(description="p99 time from the record to the wire.")


class LiveOut(BaseModel):
    id: int
    source: str
    model_name: str
    model_id: int | None = None
    gate: dict[str, Any] | None = Field(
        default=None,
        description="The version's promotion-gate verdict (usable, reason, scores) when the view "
        "started; null when the gate never measured it.",
    )
    started_by: str
    started_at: dt.datetime
    state: str = Field(description="starting, running, ended, stopped or failed.")
    message: str
    frames: int
    dropped: int
    fps: float | None
    latency_p50_ms: float | None
    latency_p99_ms: float | None
    smooth: bool
    sequential: bool
    int8: bool
    mm_per_px: float | None
    last: dict[str, Any] | None = Field(description="The newest record (as `weldpool stream`).")
    outputs: list[LiveOutputOut] = Field(default_factory=list)


class LiveRecords(BaseModel):
    records: list[dict[str, Any]]
