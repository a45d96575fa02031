"""A closed loop on the stream's output: a PI controller holds a simulated weld pool's width
while a heat-input step hits it, reading the student's measurement over MQTT.

Run (a broker first; ``weldpool_core/cell/plant.py`` documents the plant and the controller):

    mosquitto -p 1883 &
    .venv/bin/python examples/closed_loop.py --plot docs/images/closed-loop.png

Each step of the process (``--fps`` 20 a second): the plant (``WeldPoolPlant``) advances with the
arc power and the commanded travel speed; the camera (``PlantCamera``) renders the pool as a
synthetic frame; the stream's student (``weldpool_core.cell.stream``, ONNX Runtime) measures it
and the MQTT output publishes the record; the controller, a separate MQTT client as a PLC would be,
receives it and computes the speed (``PIController``), which the robot (this loop; a PLC writes
it to the robot controller) applies to the next step. The loop runs in lock-step, one process
step per answered frame, so the plot is the same however fast the machine is; the latencies
are measured in wall time: capture → record (the student), record → on the wire (the MQTT output),
capture → controller (through the broker), and capture → command back at the robot.

The same run without the controller (the speed held) shows what the disturbance does alone.
Without ``--model``, a light student is trained first on frames of the same synthetic pool at
widths of 0.7–1.35× nominal (about three minutes here; kept in ``--work``).
"""

from __future__ import annotations

import argparse
import json
import queue
import statistics
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from weldpool_core.cell.outputs import CellInfo, OutputsConfig, open_outputs
from weldpool_core.cell.outputs.mqtt import MqttOptions, parse_mqtt_url
from weldpool_core.cell.plant import PIController, PlantCamera, PlantParams, WeldPoolPlant
from weldpool_core.cell.stream import CapturedFrame, StreamStudent, run_stream

SETTLE_S = 4.0
"""The goal is judged from this long after the disturbance."""


@dataclass
class Run:
    """One simulated weld: what the plant did and what the loop measured, per frame."""

    controlled: bool
    rows: list[dict[str, float | None]] = field(default_factory=list)


def train_loop_student(folder: Path, camera: PlantCamera, steps: int) -> Path:
    """A light student trained on frames of the camera's pool at many widths."""
    from weldpool_core.io import to_rgb8
    from weldpool_core.student.data import TrainingFrame
    from weldpool_core.student.export import ensure_onnx
    from weldpool_core.student.model import student_config
    from weldpool_core.student.train import TrainConfig, train_student

    rng = np.random.default_rng(0)
    frames = []
    for index, scale in enumerate(rng.uniform(0.7, 1.35, 40)):
        drawn = camera.render(camera.plant.width_mm * float(scale), time_s=0.37 * index)
        frames.append(TrainingFrame(to_rgb8(drawn.image), drawn.mask, None, f"loop{index}"))
    print(f"training a light student on {len(frames)} frames of the pool ({steps} steps) …")
    train_student(frames, folder, student_config("light"), TrainConfig(steps=steps, device="cpu"))
    ensure_onnx(folder)
    return folder


class Controller:
    """The PLC: an MQTT client that turns each measurement into a speed command."""

    def __init__(self, url: str, pi: PIController, dt_s: float) -> None:
        import paho.mqtt.client as mqtt
        from paho.mqtt.enums import CallbackAPIVersion

        target = parse_mqtt_url(url)
        self.pi, self.dt_s = pi, dt_s
        self.commands: queue.Queue[dict[str, Any]] = queue.Queue()
        self._ready = threading.Event()
        self.client = mqtt.Client(CallbackAPIVersion.VERSION2)
        self.client.on_connect = lambda c, *_a: c.subscribe(target.topic, qos=0)
        self.client.on_subscribe = lambda *_a: self._ready.set()
        self.client.on_message = self._on_message
        self.client.connect(target.host, target.port)
        self.client.loop_start()
        if not self._ready.wait(10):
            raise SystemExit(f"The controller could not subscribe on {url}.")

    def _on_message(self, _client: Any, _data: Any, message: Any) -> None:
        record = json.loads(message.payload)
        received = time.time()
        speed = self.pi.update(record["width"], self.dt_s)
        self.commands.put(
            {"frame": record["frame"], "speed": speed, "received": received, "t": record["t"]}
        )

    def close(self) -> None:
        self.client.loop_stop()
        self.client.disconnect()


def simulate(
    controlled: bool, student: StreamStudent, camera: PlantCamera, args: argparse.Namespace
) -> Run:
    """One weld of ``args.seconds``: the heat input steps by ``args.heat_step`` at
    ``args.disturbance_at``; with ``controlled``, the controller's speed drives the plant."""
    dt = 1.0 / args.fps
    plant = WeldPoolPlant(camera.plant, dt)
    info = CellInfo("loop", student.config.k, mm_per_px=camera.mm_per_px)
    outputs = open_outputs(OutputsConfig(mqtt=MqttOptions(args.mqtt)), info)
    publisher = outputs.outputs[0]
    publisher.wait_for_subscriber(10)
    pi = PIController(args.setpoint)
    controller = Controller(args.mqtt, pi, dt) if controlled else None
    run, speed = Run(controlled), pi.nominal_speed
    try:
        for index in range(round(args.seconds * args.fps)):
            t = index * dt
            power = camera.plant.power_w * (args.heat_step if t >= args.disturbance_at else 1.0)
            width = plant.step(power, speed)
            drawn = camera.render(width, t)
            frame = CapturedFrame(
                index, time.time(), time.perf_counter(), camera.bgr(drawn), None, 0, t
            )
            stream = run_stream(iter([frame]), student, mm_per_px=camera.mm_per_px)
            record = next(stream).record
            outputs.send(record)
            row: dict[str, float | None] = {
                "t": t,
                "power_w": power,
                "speed_mm_s": speed,
                "width_mm": width,
                "measured_mm": record["width_mm"],
                "record_ms": record["latency_ms"],
                "wire_ms": publisher.counters.added_ms[-1] if publisher.counters.added_ms else None,
            }
            if controller is not None:
                command = _command_for(controller, index)
                if command is not None:
                    speed = command["speed"]
                    row["controller_ms"] = 1000 * (command["received"] - record["captured_at"])
                    row["loop_ms"] = 1000 * (time.perf_counter() - frame.captured)
            run.rows.append(row)
    finally:
        if controller is not None:
            controller.close()
        outputs.close()
    return run


def _command_for(controller: Controller, index: int) -> dict[str, Any] | None:
    """The controller's answer to frame ``index`` (None when none came within 2 s)."""
    deadline = time.monotonic() + 2.0
    while (left := deadline - time.monotonic()) > 0:
        try:
            command = controller.commands.get(timeout=left)
        except queue.Empty:
            return None
        if command["frame"] == index:
            return command
    return None


def settled(run: Run, args: argparse.Namespace, key: str) -> float | None:
    """The largest deviation from the set point after the disturbance settled (a fraction; None
    for a run too short to settle)."""
    after = [r[key] for r in run.rows if r["t"] >= args.disturbance_at + SETTLE_S]
    deviations = [abs(float(v) - args.setpoint) / args.setpoint for v in after if v is not None]
    return round(max(deviations), 4) if deviations else None


def latency_budget(run: Run) -> dict[str, dict[str, float]]:
    budget = {}
    for key, name in (
        ("record_ms", "capture → record (student)"),
        ("wire_ms", "record → on the wire (MQTT output)"),
        ("controller_ms", "capture → controller (through the broker)"),
        ("loop_ms", "capture → command back at the robot"),
    ):
        values = [float(r[key]) for r in run.rows if r.get(key) is not None]  # type: ignore[arg-type]
        if values:
            budget[name] = {
                "p50": round(statistics.median(values), 3),
                "p99": round(float(np.percentile(values, 99)), 3),
            }
    return budget


def plot(runs: list[Run], args: argparse.Namespace, budget: dict[str, Any], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, (top, bottom) = plt.subplots(
        2, 1, figsize=(9, 6.2), sharex=True, height_ratios=[2.2, 1]
    )
    closed, open_loop = runs
    t = [r["t"] for r in closed.rows]
    band = (args.setpoint * 0.95, args.setpoint * 1.05)
    top.axhspan(*band, color="#2f9e44", alpha=0.10, label="set point ± 5 %")
    top.axhline(args.setpoint, color="#2f9e44", lw=1, ls="--")
    top.plot(
        t, [r["width_mm"] for r in open_loop.rows], color="#e8590c", label="without the controller"
    )
    top.plot(
        t,
        [r["width_mm"] for r in closed.rows],
        color="#1c7ed6",
        lw=2,
        label="with the PI controller",
    )
    top.plot(
        t,
        [r["measured_mm"] for r in closed.rows],
        color="#1c7ed6",
        lw=0.8,
        alpha=0.5,
        label="the student's measurement (closed loop)",
    )
    top.axvline(args.disturbance_at, color="#868e96", lw=1, ls=":")
    top.text(
        args.disturbance_at + 0.1,
        0.96,
        f"heat input +{(args.heat_step - 1) * 100:.0f} %",
        transform=top.get_xaxis_transform(),
        color="#495057",
        fontsize=9,
        va="top",
    )
    top.set_ylabel("pool width (mm)")
    top.legend(loc="upper left", fontsize=8)
    top.set_title("A PI controller on the stream's MQTT output holds the pool width")
    bottom.plot(t, [r["speed_mm_s"] for r in closed.rows], color="#1c7ed6", label="commanded speed")
    bottom.plot(t, [r["speed_mm_s"] for r in open_loop.rows], color="#e8590c", label="held speed")
    bottom.set_ylabel("travel speed (mm/s)")
    bottom.set_xlabel("process time (s)")
    bottom.legend(loc="upper left", fontsize=8)
    lines = [f"{name}: p50 {v['p50']:.1f} ms · p99 {v['p99']:.1f} ms" for name, v in budget.items()]
    top.text(
        0.99,
        0.03,
        "latency (wall time)\n" + "\n".join(lines),
        transform=top.transAxes,
        ha="right",
        va="bottom",
        fontsize=7.5,
        family="monospace",
        bbox={"facecolor": "white", "alpha": 0.85, "lw": 0},
    )
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    print(f"plot: {path}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, help="A student folder (default: train one).")
    parser.add_argument(
        "--work", type=Path, default=Path.home() / ".cache" / "weldpool" / "closed-loop"
    )
    parser.add_argument("--steps", type=int, default=600, help="Training steps without --model.")
    parser.add_argument("--mqtt", default="mqtt://127.0.0.1:1883/weldpool/loop")
    parser.add_argument("--seconds", type=float, default=15.0)
    parser.add_argument("--fps", type=float, default=20.0)
    parser.add_argument("--setpoint", type=float, default=PlantParams().width_mm)
    parser.add_argument("--disturbance-at", type=float, default=4.0)
    parser.add_argument("--heat-step", type=float, default=1.3)
    parser.add_argument("--plot", type=Path, help="Write the PNG here.")
    parser.add_argument("--json", type=Path, help="Write the runs and the budget here.")
    args = parser.parse_args()
    camera = PlantCamera()
    model = args.model
    if model is None:
        model = args.work / "student"
        if not (model / "model.onnx").is_file():
            train_loop_student(model, camera, args.steps)
    student = StreamStudent(model, "onnx", "cpu")
    runs = [simulate(True, student, camera, args), simulate(False, student, camera, args)]
    budget = latency_budget(runs[0])
    result = {
        "closed_loop_max_deviation": settled(runs[0], args, "width_mm"),
        "closed_loop_measured_max_deviation": settled(runs[0], args, "measured_mm"),
        "open_loop_max_deviation": settled(runs[1], args, "width_mm"),
        "frames": len(runs[0].rows),
        "commands": sum(1 for r in runs[0].rows if r.get("loop_ms") is not None),
        "latency_ms": budget,
    }
    print(json.dumps(result, indent=1))
    if args.json:
        args.json.write_text(json.dumps({**result, "runs": [r.rows for r in runs]}))
    if args.plot:
        plot(runs, args, budget, args.plot)


if __name__ == "__main__":
    main()
