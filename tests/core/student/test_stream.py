"""Live inference: sources that keep up by dropping, records in frame pixels, two backends alike."""

from __future__ import annotations

import contextlib
import http.server
import itertools
import json
import os
import shutil
import socket
import socketserver
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import zmq

from tests.core.student.common import TINY_STUDENT
from tests.helpers import REPO, run_cli, write_video
from tests.mqtt import clear_retained, unique_topic
from weldpool_core.cell.smoothing import KeypointSmoother
from weldpool_core.cell.stream import (
    CapturedFrame,
    FrameSource,
    StreamStudent,
    analyse,
    parse_source,
    record_fields,
    run_stream,
)
from weldpool_core.errors import InvalidInputError
from weldpool_core.heatmap import keypoints_from_mask
from weldpool_core.student.data import FrameGeometry
from weldpool_core.student.export import export_student
from weldpool_core.student.train import TrainResult


def _index_of(frame: CapturedFrame) -> int:
    return round(float(frame.bgr[2:6, 2:6].mean()) / 6)


def test_sources_are_told_apart_and_a_missing_file_is_one_sentence(tmp_path: Path) -> None:
    assert parse_source("0") == (0, True)
    assert parse_source("rtsp://cell-3.local/stream") == ("rtsp://cell-3.local/stream", True)
    video = write_video(tmp_path / "run.avi", 2)
    assert parse_source(str(video)) == (str(video), False)
    with pytest.raises(InvalidInputError, match="no video file"):
        parse_source(str(tmp_path / "absent.mp4"))
    (tmp_path / "notes.txt").write_text("not a video")
    with pytest.raises(InvalidInputError, match="cannot open"):
        FrameSource(str(tmp_path / "notes.txt"))


def test_a_file_gives_every_frame_in_order_with_its_recording_time(tmp_path: Path) -> None:
    video = write_video(tmp_path / "run.avi", 12, fps=20.0)
    with FrameSource(str(video)) as source:
        frames = list(source)
    assert [f.index for f in frames] == list(range(12))
    assert [_index_of(f) for f in frames] == list(range(12))  # the pixels are that frame's
    assert [f.time_s for f in frames] == pytest.approx([i / 20.0 for i in range(12)])
    assert sum(f.dropped for f in frames) == 0 and frames[0].bgr.shape == (64, 96, 3)


def test_a_live_source_drops_stale_frames_and_says_how_many(tmp_path: Path) -> None:
    video = write_video(tmp_path / "run.avi", 40, fps=100.0)
    delivered = []
    with FrameSource(str(video), realtime=True) as source:
        for frame in source:
            delivered.append(frame)
            time.sleep(0.05)  # inference five times slower than the camera
    assert source.read_count == 40 and source.dropped > 10
    assert len(delivered) + sum(f.dropped for f in delivered) == 40
    for before, after in itertools.pairwise(delivered):
        assert after.index - before.index - 1 == after.dropped  # each gap is counted
        assert _index_of(after) == after.index  # the newest frame, not an old one


def test_a_record_carries_the_widths_rolling_stability() -> None:
    """The stream's stability figure is the signature's rolling CV of the width (frame
    pixels): a pool that swings between 40 and 60 px wide is unstable, a steady one is not."""
    from weldpool_core.signature import RollingStability

    geometry = FrameGeometry.fit(64, 64, 64, "letterbox")
    stability = RollingStability()
    records = []
    for index, half in enumerate([10, 10, 10, 10, 5, 15, 5, 15]):
        mask = np.zeros((64, 64), np.float32)
        mask[32 - half : 32 + half, 8:56] = 1.0  # 48 long, 2·half wide
        frame = CapturedFrame(index, 0.0, 0.0, np.zeros((64, 64, 3), np.uint8), time_s=index / 10)
        records.append(
            analyse(frame, mask, mask, geometry, TINY_STUDENT, stability=stability).record
        )
    assert records[0]["stability_cv"] is None and records[0]["unstable"] is False
    assert records[3]["stability_cv"] == pytest.approx(0.0, abs=1e-6)
    widths = [r["width_px"] for r in records[2:]]  # the last 0.5 s at 10 fps: t ≥ 0.2
    expected = float(np.std(widths, ddof=1) / np.mean(widths))
    assert records[-1]["stability_cv"] == pytest.approx(expected, abs=1e-3)
    assert records[-1]["unstable"] is True
    plain = analyse(frame, mask, mask, geometry, TINY_STUDENT).record
    assert (plain["stability_cv"], plain["unstable"]) == (None, False)


def test_a_record_is_in_frame_pixels_and_millimetres() -> None:
    """Known outputs on a 64² letterboxed input of a 160×100 frame: the record's numbers are the
    frame's, so a lost offset, scale or swapped axis shows (keypoints from the heatmap's peaks
    here, and from the mask's outline below)."""
    config = replace(TINY_STUDENT, keypoints="heatmap")
    geometry = FrameGeometry.fit(100, 160, 64, "letterbox")  # inner 64×40, offset y 12
    assert (geometry.offset_x, geometry.offset_y) == (0, 12)
    mask = np.zeros((64, 64), np.float32)
    mask[14:38, 8:56] = 1.0  # input rows 14..37 → frame rows 5..64, cols 8..55 → 20..139
    corners = np.array([[9, 15], [54, 15], [54, 36], [9, 36]], float)
    heatmap = np.zeros((64, 64), np.float32)
    yy, xx = np.mgrid[0:64, 0:64]
    for x, y in corners:
        heatmap += np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / 2.0).astype(np.float32)
    frame = CapturedFrame(0, 0.0, 0.0, np.zeros((100, 160, 3), np.uint8))
    record = analyse(frame, mask, heatmap, geometry, config, mm_per_px=0.05, travel_deg=0).record
    assert set(record) == set(record_fields())
    assert record["area_px"] == pytest.approx(120 * 60, rel=0.01)
    assert record["length_px"] == pytest.approx(120, abs=0.5)
    assert record["width_px"] == pytest.approx(60, abs=0.5)
    assert record["centroid"] == pytest.approx([79.5, 34.5], abs=0.3)
    assert record["length_mm"] == pytest.approx(6.0, abs=0.03)
    assert record["area_mm2"] == pytest.approx(7200 * 0.0025, rel=0.01)
    found = np.array(record["keypoints"])
    expected = geometry.to_frame(corners)  # (x, y) · 2.5, y shifted by the letterbox
    assert len(found) == 4
    assert np.abs(np.sort(found, axis=0) - np.sort(expected, axis=0)).max() < 1.5
    outline = analyse(frame, mask, heatmap, geometry, TINY_STUDENT).record["keypoints"]
    full = np.zeros((100, 160), bool)
    full[5:65, 20:140] = True  # the same pool in frame pixels
    # Within 2 model pixels (5 frame px; Algorithm 1 smooths 9 px at either size, a rounder
    # corner at 64²); a lost letterbox offset is 30 px, a lost scale 60 and more.
    assert np.abs(np.array(outline) - keypoints_from_mask(full)).max() < 5
    assert record["ambiguity"] == 0.0
    hesitant = mask.copy()
    hesitant[12:14, 8:40] = 0.5  # a band the student is unsure of
    unsure = analyse(frame, hesitant, heatmap, geometry, config).record
    assert unsure["ambiguity"] == pytest.approx(64 / (24 * 48 + 64), abs=1e-3)


@pytest.fixture()
def model_dir(trained: TrainResult, tmp_path: Path) -> Path:
    copy = Path(shutil.copytree(trained.model_dir, tmp_path / "model"))
    for name in ("model.onnx", "model.torchscript.pt", "export.json"):
        (copy / name).unlink(missing_ok=True)
    return copy


def test_onnx_and_torch_streams_give_the_same_records(model_dir: Path, tmp_path: Path) -> None:
    with pytest.raises(InvalidInputError, match="export the student to ONNX first"):
        StreamStudent(model_dir, "onnx")
    export_student(model_dir, ["onnx"])
    video = write_video(tmp_path / "run.avi", 8)
    records, outputs = {}, {}
    for backend in ("onnx", "torch"):
        # torch's thread count is process-wide: leave it (other tests compare trained weights)
        student = StreamStudent(model_dir, backend, "cpu", threads=1 if backend == "onnx" else None)
        with FrameSource(str(video), prepare=student.prepare) as source:
            results = list(run_stream(source, student))
        records[backend] = [r.record for r in results]
        outputs[backend] = [student(*student.prepare(r.frame.bgr))[:2] for r in results]
    assert len(records["onnx"]) == len(records["torch"]) == 8
    # the same model in both runtimes: the same S×S mask and heatmap. Keypoints are the heatmap's
    # modes, and a barely trained model's near-equal modes may swap order on a rounding
    # difference, so the records are compared on what does not hinge on a tie.
    for (mask, heatmap), (mask_t, heatmap_t) in zip(outputs["onnx"], outputs["torch"], strict=True):
        assert np.abs(mask - mask_t).max() < 1e-4 and np.abs(heatmap - heatmap_t).max() < 1e-4
    for ours, theirs in zip(records["onnx"], records["torch"], strict=True):
        assert ours["area_px"] == pytest.approx(theirs["area_px"], abs=40)
        assert len(ours["keypoints"]) == len(theirs["keypoints"])
        assert ours["latency_ms"] > 0
    with pytest.raises(InvalidInputError, match="needs the PyTorch backend"):
        student = StreamStudent(model_dir, "onnx")
        batch, geometry = student.prepare(np.zeros((64, 96, 3), np.uint8))
        student(batch, geometry, samples=2)
    torch_student = StreamStudent(model_dir, "torch", "cpu")
    with FrameSource(str(video), max_frames=2) as source:
        scored = [r.record for r in run_stream(source, torch_student, samples=2)]
    assert len(scored) == 2 and all(0 <= r["uncertainty"] <= 1 for r in scored)


def test_smoothing_keeps_the_raw_keypoints_beside_the_steady_ones(
    model_dir: Path, tmp_path: Path
) -> None:
    video = write_video(tmp_path / "run.avi", 6)
    student = StreamStudent(model_dir, "torch", "cpu")
    with FrameSource(str(video)) as source:
        results = list(run_stream(source, student, smoother=KeypointSmoother(student.config.k)))
    first = results[0].record
    assert first["keypoints_raw"] is not None
    assert sorted(map(tuple, first["keypoints"])) == sorted(map(tuple, first["keypoints_raw"]))


def test_the_cli_publishes_every_frame_to_a_subscriber(model_dir: Path, tmp_path: Path) -> None:
    """`weldpool stream VIDEO --publish`: a controller subscribed first receives every frame's
    record, the same as stdout and the --record file; the ONNX file is exported on first use."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    video = write_video(tmp_path / "run.avi", 8)
    recorded = tmp_path / "run.jsonl"
    command = [sys.executable, "-m", "app", "stream", str(video), "--model", str(model_dir)]
    command += ["--publish", f"tcp://127.0.0.1:{port}", "--wait-for-subscriber", "60"]
    command += ["--record", str(recorded), "--mm-per-px", "0.1"]
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WELDPOOL_HOME": str(tmp_path / "home")}
    process = subprocess.Popen(
        command, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    context = zmq.Context()
    subscriber = context.socket(zmq.SUB)
    subscriber.setsockopt(zmq.SUBSCRIBE, b"")
    subscriber.connect(f"tcp://127.0.0.1:{port}")
    received = []
    try:
        while len(received) < 8 and subscriber.poll(90_000):
            received.append(json.loads(subscriber.recv()))
        stdout, stderr = process.communicate(timeout=60)
    finally:
        process.kill()
        subscriber.close()
        context.term()
    assert process.returncode == 0, stderr
    assert [r["frame"] for r in received] == list(range(8))
    assert received[0]["length_mm"] == pytest.approx(received[0]["length_px"] * 0.1, abs=0.01)
    printed = [json.loads(line) for line in stdout.splitlines()]
    assert printed == received
    assert [json.loads(line) for line in recorded.read_text().splitlines()] == received
    summary = json.loads(stderr.strip().splitlines()[-1])
    assert (summary["frames"], summary["dropped"], summary["backend"]) == (8, 0, "onnx")
    assert summary["latency_p99_ms"] >= summary["latency_p50_ms"] > 0
    assert (model_dir / "model.onnx").is_file()
    missing = run_cli("stream", str(video), "--model", str(tmp_path / "nowhere"))
    assert missing.returncode == 2
    nowhere = tmp_path / "nowhere"
    assert missing.stderr.strip() == f"weldpool: There is no student folder '{nowhere}'."


class _MjpegCamera(http.server.BaseHTTPRequestHandler):
    """A network camera: endless JPEG frames at 30 fps over HTTP (multipart/x-mixed-replace)."""

    def do_GET(self) -> None:
        self.send_response(200)
        self.send_header("Content-Type", "multipart/x-mixed-replace; boundary=frame")
        self.end_headers()
        index = 0
        try:
            while True:
                image = np.full((64, 96, 3), 6 * (index % 40), np.uint8)
                jpeg = cv2.imencode(".jpg", image)[1].tobytes()
                head = f"--frame\r\nContent-Type: image/jpeg\r\nContent-Length: {len(jpeg)}\r\n\r\n"
                self.wfile.write(head.encode() + jpeg + b"\r\n")
                index += 1
                time.sleep(1 / 30)
        except OSError:
            return

    def log_message(self, *args: object) -> None:
        return


def test_a_network_camera_is_live_and_keeps_up_by_dropping() -> None:
    server = socketserver.ThreadingTCPServer(("127.0.0.1", 0), _MjpegCamera)
    server.daemon_threads = True
    threading.Thread(target=server.serve_forever, daemon=True).start()
    url = f"http://127.0.0.1:{server.server_address[1]}/camera.mjpg"
    try:
        with FrameSource(url) as source:
            assert source.live
            delivered = []
            for frame in source:
                delivered.append(frame)
                time.sleep(0.1)  # three camera frames per frame processed
                if len(delivered) == 8:
                    break
    finally:
        server.shutdown()
        server.server_close()
    assert sum(f.dropped for f in delivered[1:]) >= 8
    for before, after in itertools.pairwise(delivered):
        assert after.index - before.index - 1 == after.dropped
        assert after.time_s > before.time_s


def test_a_failure_on_the_reader_thread_reaches_the_consumer(tmp_path: Path) -> None:
    video = write_video(tmp_path / "run.avi", 5)

    def broken(_frame: object) -> None:
        raise InvalidInputError("This frame cannot be prepared.")

    with (
        FrameSource(str(video), prepare=broken) as source,
        pytest.raises(InvalidInputError, match="cannot be prepared"),
    ):
        list(source)


def test_the_cli_serves_opcua_and_publishes_mqtt_to_real_clients(
    model_dir: Path, tmp_path: Path, mqtt_broker: tuple[str, int]
) -> None:
    """`weldpool stream VIDEO --opcua … --mqtt …`: an asyncua client subscribed first sees the
    frame counter reach the last frame, a subscriber on mosquitto receives every frame, both in
    millimetres with a scale; the summary lists both outputs."""
    import asyncio

    from asyncua import Client, ua

    from tests.mqtt import Listener, free_port

    host, port = mqtt_broker
    opc_port = free_port()
    listener = Listener(host, port, unique_topic("cli"))
    video = write_video(tmp_path / "run.avi", 8)
    command = [sys.executable, "-m", "app", "stream", str(video), "--model", str(model_dir)]
    command += [
        "--opcua",
        f"opc.tcp://127.0.0.1:{opc_port}",
        "--mqtt",
        listener.url,
    ]
    command += ["--mqtt-qos", "1", "--mm-per-px", "0.1", "--quiet", "--wait-for-subscriber", "60"]
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WELDPOOL_HOME": str(tmp_path / "home")}
    process = subprocess.Popen(
        command, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    counters: list[int] = []
    widths: list[float] = []

    class Handler:
        def datachange_notification(self, node: Any, value: Any, _data: object) -> None:
            name = node.nodeid.Identifier
            (counters if name == "WeldPool.FrameCounter" else widths).append(value)

    async def watch() -> float:
        url = f"opc.tcp://127.0.0.1:{opc_port}/weldpool/"
        for _ in range(600):  # the CLI starts (imports, ONNX export) before it serves
            try:
                client = Client(url)
                await client.connect()
                break
            except (TimeoutError, OSError):
                await asyncio.sleep(0.2)
        try:
            index = await client.get_namespace_index("urn:weldpool:stream")
            subscription = await client.create_subscription(10, Handler())
            await subscription.subscribe_data_change(
                [
                    client.get_node(ua.NodeId(f"WeldPool.{n}", index))
                    for n in ("Width", "FrameCounter")
                ]
            )
            while 7 not in counters and process.poll() is None:
                await asyncio.sleep(0.05)
            return float(widths[-1])
        finally:
            with contextlib.suppress(ConnectionError):  # the stream ended and closed it first
                await client.disconnect()

    try:
        opc_width = asyncio.run(watch())
        stdout, stderr = process.communicate(timeout=60)
        listener.wait_for(lambda: len(listener.frames(listener.topic)) == 8)
    finally:
        process.kill()
        listener.close()
    assert process.returncode == 0, stderr
    assert stdout == ""
    frames = listener.frames(listener.topic)
    assert [m["frame"] for m in frames] == list(range(8))
    assert counters[-1] == 7 and counters == sorted(counters)
    assert opc_width == pytest.approx(frames[-1]["width"], abs=1e-3)
    summary = json.loads(stderr.strip().splitlines()[-1])
    kinds = {o["kind"]: o for o in summary["outputs"]}
    assert kinds["mqtt"]["sent"] == 8 and kinds["opcua"]["sent"] + kinds["opcua"]["skipped"] == 8


def test_the_cli_refuses_a_port_in_use_and_bad_addresses_in_one_line(
    model_dir: Path, tmp_path: Path
) -> None:
    video = write_video(tmp_path / "run.avi", 2)
    base = ("stream", str(video), "--model", str(model_dir), "--quiet")
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        busy = run_cli(*base, "--opcua", f"opc.tcp://127.0.0.1:{port}")
    assert busy.returncode == 2 and "Traceback" not in busy.stderr
    assert busy.stderr.strip().splitlines()[-1] == (
        f"weldpool: Cannot serve OPC UA on 'opc.tcp://127.0.0.1:{port}': the port is in use; "
        "choose another port."
    )
    # The other refusals are the library's, tested in tests/core/outputs.
    nowhere = run_cli(*base, "--mqtt", "mqtt://no-such-broker.invalid/t")
    assert nowhere.returncode == 2, nowhere.stderr
    assert "does not resolve" in nowhere.stderr and "Traceback" not in nowhere.stderr
    lonely = run_cli(*base, "--mqtt-qos", "1")
    assert lonely.returncode == 2 and "need --mqtt URL" in lonely.stderr


def test_the_closed_loop_example_answers_every_frame_over_mqtt(
    model_dir: Path, tmp_path: Path, mqtt_broker: tuple[str, int]
) -> None:
    """examples/closed_loop.py: each frame's record goes through mosquitto to the controller and
    its speed comes back before the next step; the run without the controller holds the speed.
    (The tiny student's widths mean little: the loop's meaning is tested in test_plant.py.)"""
    export_student(model_dir, ["onnx"])
    host, port = mqtt_broker
    out = tmp_path / "loop.json"
    command = [sys.executable, str(REPO / "examples" / "closed_loop.py"), "--model", str(model_dir)]
    topic = unique_topic("loop")
    command += ["--mqtt", f"mqtt://{host}:{port}/{topic}", "--seconds", "1.5"]
    command += ["--disturbance-at", "0.5", "--json", str(out)]
    env = {**os.environ, "HF_HUB_OFFLINE": "1"}
    done = subprocess.run(command, cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    clear_retained(host, port, f"{topic}/status")  # the broker may be shared (CI's)
    assert done.returncode == 0, done.stderr
    result = json.loads(out.read_text())
    assert result["frames"] == 30 and result["commands"] == 30
    closed, held = result["runs"]
    assert {r["speed_mm_s"] for r in held} == {5.0}
    assert len({r["speed_mm_s"] for r in closed}) > 1  # the controller's commands drove it
    assert [r["power_w"] for r in closed][9:11] == [2000.0, 2600.0]  # the step at 0.5 s
    stages = result["latency_ms"]
    assert len(stages) == 4 and all(v["p99"] >= v["p50"] > 0 for v in stages.values())
