"""``weldpool stream``: the student on a camera, a URL or a video, one JSON line per frame."""

from __future__ import annotations

import json
import sys
import time
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import IO, Any

import click

from app.cli.base import fail, friendly_errors, load_settings, main, open_sessions
from app.core.errors import WeldpoolError


def promoted_model_dir() -> tuple[Path, bool]:
    """The promoted student's folder in this home's database, and whether the promotion gate
    found it usable (False: promoted by force; the outputs then say the stream is not healthy)."""
    from app.storage import open_storage
    from app.training.service import model_folder, promoted_model

    settings = load_settings()
    with open_sessions(settings)() as session:
        model = promoted_model(session)
        if model is None or not model.checkpoint_path:
            raise WeldpoolError(
                "No student is promoted yet; train and promote one, or give --model MODEL_DIR."
            )
        gate = model.gate or {}
        if gate.get("usable") is False:  # as the live view says it: promoted by force
            click.echo(
                f"weldpool: warning: {model.name} is not usable by the promotion gate "
                f"({gate.get('reason') or 'worse than the teacher'}); its masks may be worse "
                "than the teacher's.",
                err=True,
            )
        elif not gate:
            click.echo(
                f"weldpool: warning: {model.name} was not measured by the promotion gate.",
                err=True,
            )
        return model_folder(open_storage(settings), model), gate.get("usable") is not False


@main.command("stream")
@click.argument("source")
@click.option(
    "--model",
    "model",
    default="promoted",
    show_default=True,
    help="A student's MODEL_DIR, or 'promoted' for this home's promoted version.",
)
@click.option("--backend", type=click.Choice(["onnx", "torch"]), default="onnx", show_default=True)
@click.option("--device", default="auto", show_default=True, help="For torch: cpu, cuda, auto.")
@click.option("--threads", type=click.IntRange(min=1), help="Inference threads (default: all).")
@click.option(
    "--publish", metavar="ADDRESS", help="ZeroMQ address to publish on, e.g. tcp://127.0.0.1:5556."
)
@click.option(
    "--opcua",
    metavar="URL",
    help="Serve the values over OPC UA for PLCs, e.g. opc.tcp://0.0.0.0:4840 (read-only).",
)
@click.option(
    "--opcua-security",
    type=click.Choice(["none", "sign-encrypt"]),
    default="none",
    show_default=True,
    help="none for a lab bench; sign-encrypt (Basic256Sha256) for the cell, with a certificate.",
)
@click.option(
    "--opcua-cert",
    type=click.Path(dir_okay=False, path_type=Path),
    help="The server's certificate (DER or PEM).",
)
@click.option(
    "--opcua-key", type=click.Path(dir_okay=False, path_type=Path), help="Its private key (PEM)."
)
@click.option(
    "--opcua-trust",
    type=click.Path(file_okay=False, path_type=Path),
    help="With sign-encrypt: accept only client certificates found in this folder.",
)
@click.option(
    "--mqtt",
    metavar="URL",
    help="Publish one JSON message per frame, e.g. mqtt://broker:1883/cell1/pool (mqtts:// TLS).",
)
@click.option("--mqtt-qos", type=click.IntRange(0, 1), default=0, show_default=True)
@click.option("--mqtt-retain", is_flag=True, help="Retain the newest message on the broker.")
@click.option(
    "--mqtt-rate",
    type=click.FloatRange(min=0.1),
    help="At most this many messages a second (the newest frame each time); default: every frame.",
)
@click.option(
    "--mqtt-username",
    help="Broker user (the password from WELDPOOL_MQTT_PASSWORD, never on the command line).",
)
@click.option("--mqtt-ca", type=click.Path(dir_okay=False, path_type=Path), help="TLS CA file.")
@click.option(
    "--mqtt-cert", type=click.Path(dir_okay=False, path_type=Path), help="TLS client certificate."
)
@click.option("--mqtt-key", type=click.Path(dir_okay=False, path_type=Path), help="TLS client key.")
@click.option(
    "--stale-ms",
    type=click.FloatRange(min=10),
    default=500.0,
    show_default=True,
    help="No frame for this long: OPC UA's Healthy turns false, MQTT's status says stale.",
)
@click.option(
    "--wait-for-subscriber",
    type=click.FloatRange(min=0),
    default=0.0,
    show_default=True,
    help="Seconds to wait for a ZeroMQ subscriber, an OPC UA subscription and the MQTT broker "
    "before the first frame.",
)
@click.option(
    "--record",
    "record_path",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Also write every record to this JSON-lines file.",
)
@click.option("--quiet", is_flag=True, help="No JSON lines on stdout (use --publish or --record).")
@click.option(
    "--smooth",
    type=click.Choice(["none", "one-euro"]),
    default="one-euro",
    show_default=True,
    help="Temporal filter on keypoint tracks (keypoints_raw keeps the per-frame ones).",
)
@click.option("--min-cutoff", type=click.FloatRange(min=0.001), default=None, help="one-euro, Hz.")
@click.option("--beta", type=click.FloatRange(min=0), default=None, help="one-euro speed factor.")
@click.option("--mm-per-px", type=click.FloatRange(min=0, min_open=True), help="Scale for mm.")
@click.option("--travel-deg", type=float, help="Travel direction (0° right, 90° down).")
@click.option(
    "--samples",
    type=click.IntRange(min=0),
    default=0,
    show_default=True,
    help="Latent draws for the uncertainty (torch backend; 0: none).",
)
@click.option(
    "--sequential",
    is_flag=True,
    help="Use the folder's sequential student (weldpool train-sequential): steadier masks "
    "and keypoints from the frames before.",
)
@click.option(
    "--int8",
    is_flag=True,
    help="Run the quantized student (model.int8.onnx, weldpool export-student --format "
    "onnx-int8): 1.5–3× faster on a CPU, its masks checked against the float ones.",
)
@click.option(
    "--classes",
    "classes",
    metavar="NAMES",
    help="Learned classes whose geometry each record adds (comma-separated, e.g. wire,torch; "
    "'none' for none). Default: every class the student learned beside the pool.",
)
@click.option("--realtime", is_flag=True, help="Read a file at its frame rate, dropping stale.")
@click.option("--max-frames", type=click.IntRange(min=1), help="Stop after this many frames.")
@click.option(
    "--decoder-threads",
    type=click.IntRange(min=0),
    default=1,
    show_default=True,
    help="Video decoder threads (0: OpenCV's default, one per core); the rest go to inference.",
)
@friendly_errors
def stream_cmd(
    source: str,
    model: str,
    backend: str,
    device: str,
    threads: int | None,
    publish: str | None,
    wait_for_subscriber: float,
    record_path: Path | None,
    quiet: bool,
    smooth: str,
    min_cutoff: float | None,
    beta: float | None,
    mm_per_px: float | None,
    travel_deg: float | None,
    samples: int,
    sequential: bool,
    int8: bool,
    classes: str | None,
    realtime: bool,
    max_frames: int | None,
    decoder_threads: int,
    **cell: Any,
) -> None:
    """Run a student on SOURCE (a video file, a camera index such as 0, or an RTSP/HTTP URL) and
    emit one JSON line per frame: keypoints, pool area / length / width, ambiguity, latency.
    --publish (ZeroMQ), --opcua and --mqtt send the same values to a controller.

    A live source keeps up by dropping stale frames (each record says how many were dropped
    before it); a file is read frame by frame unless --realtime. A summary (fps, p50 / p99
    latency) goes to stderr at the end; Ctrl-C stops cleanly.
    """
    from weldpool_core.cell.stream import StreamOptions, open_stream

    model_dir, usable = _checked_model_dir(model, record_path, samples, backend, sequential)
    names = _class_names(classes)
    config, info = _cell_outputs(publish, cell, model_dir, usable, mm_per_px, names)
    options = StreamOptions(
        backend=backend,
        device=device,
        threads=threads,
        sequential=sequential,
        int8=int8,
        smoothing=_smoothing(smooth, min_cutoff, beta),
        mm_per_px=mm_per_px,
        travel_deg=travel_deg,
        samples=samples,
        realtime=realtime,
        max_frames=max_frames,
        decoder_threads=decoder_threads or None,
        classes=names,
    )
    outputs = _Outputs(quiet)
    started = time.perf_counter()
    try:
        outputs.open(config, info, wait_for_subscriber, record_path)
        status = partial(_status, model_dir)
        with open_stream(source, model_dir, options, status=status) as results:
            started = time.perf_counter()
            for result in results:
                outputs.emit(result.record)
    except KeyboardInterrupt:
        pass
    finally:
        outputs.close()
    report: dict[str, Any] = {
        "source": source,
        "model": str(model_dir),
        "backend": "onnx-int8" if int8 else backend,
        **outputs.summary(time.perf_counter() - started),
    }
    click.echo(json.dumps(report), err=True)


def _class_names(text: str | None) -> tuple[str, ...] | None:
    """``--classes``: None (every learned class), ``()`` for 'none', else the names."""
    if text is None:
        return None
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    return () if names == ("none",) else names


@main.command("opcua-certificate")
@click.argument("folder", type=click.Path(file_okay=False, path_type=Path))
@click.option(
    "--host", default=None, help="The name clients reach the server by (default: this host's)."
)
@click.option("--days", type=click.IntRange(1, 3650), default=365, show_default=True)
@friendly_errors
def opcua_certificate_cmd(folder: Path, host: str | None, days: int) -> None:
    """Make a self-signed certificate and key for `weldpool stream --opcua-security
    sign-encrypt` in FOLDER (clients, e.g. the PLC, must be told to trust the certificate)."""
    import socket

    from weldpool_core.cell.outputs.opcua_security import make_certificate

    certificate, key = make_certificate(folder, host or socket.gethostname(), days)
    click.echo(f"--opcua-cert {certificate} --opcua-key {key}")


def _checked_model_dir(
    model: str, record_path: Path | None, samples: int, backend: str, sequential: bool
) -> tuple[Path, bool]:
    """The student folder to stream, and whether the promotion gate found it usable, after the
    options that cannot work together are refused."""
    if record_path is not None and not record_path.parent.is_dir():
        fail(f"There is no folder {str(record_path.parent)!r} for --record; create it first.")
    usable = True
    if model == "promoted":
        model_dir, usable = promoted_model_dir()
    else:
        model_dir = Path(model)
    if not model_dir.is_dir():
        fail(f"There is no student folder {str(model_dir)!r}.")
    if samples and backend != "torch":
        fail("--samples needs --backend torch (the uncertainty draws the latent in PyTorch).")
    if samples and sequential:
        fail("--samples scores the per-frame student; leave out --sequential to use it.")
    return model_dir, usable


def _cell_outputs(
    publish: str | None,
    cell: dict[str, Any],
    model_dir: Path,
    usable: bool,
    mm_per_px: Any,
    classes: tuple[str, ...] | None,
) -> tuple[Any, Any]:
    """The outputs the options ask for (ZeroMQ, OPC UA, MQTT), and what they know of the run
    (``classes``: the ``--classes`` names, None for every learned class)."""
    from weldpool_core.cell.class_geometry import chosen_classes
    from weldpool_core.cell.outputs import CellInfo, OutputsConfig
    from weldpool_core.student.checkpoint import read_student_config

    config = OutputsConfig(
        zeromq=publish,
        opcua=_opcua_options(
            cell["opcua"],
            cell["opcua_security"],
            cell["opcua_cert"],
            cell["opcua_key"],
            cell["opcua_trust"],
        ),
        mqtt=_mqtt_options(
            cell["mqtt"],
            cell["mqtt_qos"],
            cell["mqtt_retain"],
            cell["mqtt_rate"],
            cell["mqtt_username"],
            cell["mqtt_ca"],
            cell["mqtt_cert"],
            cell["mqtt_key"],
        ),
    )
    student = read_student_config(model_dir)
    info = CellInfo(
        model=model_dir.name,
        keypoints=student.k,
        mm_per_px=mm_per_px,
        model_usable=usable,
        stale_ms=cell["stale_ms"],
        classes=chosen_classes(student.classes, classes),
    )
    return config, info


def _opcua_options(
    url: str | None,
    security: str,
    certificate: Path | None,
    key: Path | None,
    trust: Path | None,
) -> Any:
    if url is None:
        if certificate or key or trust or security != "none":
            fail("--opcua-security, --opcua-cert, --opcua-key and --opcua-trust need --opcua URL.")
        return None
    from weldpool_core.cell.outputs.opcua import OpcUaOptions

    return OpcUaOptions(url, security, certificate, key, trust)


def _mqtt_options(
    url: str | None,
    qos: int,
    retain: bool,
    rate: float | None,
    username: str | None,
    ca_file: Path | None,
    cert_file: Path | None,
    key_file: Path | None,
) -> Any:
    if url is None:
        if qos or retain or rate or username or ca_file or cert_file or key_file:
            fail("The --mqtt-… options need --mqtt URL.")
        return None
    import os

    from weldpool_core.cell.outputs.mqtt import MqttOptions

    return MqttOptions(
        url,
        qos,
        retain,
        rate,
        username,
        os.environ.get("WELDPOOL_MQTT_PASSWORD"),
        ca_file,
        cert_file,
        key_file,
    )


def _smoothing(smooth: str, min_cutoff: float | None, beta: float | None) -> Any:
    """The One-Euro filter's settings (None: raw keypoints)."""
    from weldpool_core.cell.smoothing import SmoothingParams

    if smooth != "one-euro":
        return None
    params = SmoothingParams()
    params = replace(params, min_cutoff=params.min_cutoff if min_cutoff is None else min_cutoff)
    return replace(params, beta=params.beta if beta is None else beta)


class _Outputs:
    """Where each record goes (stdout, the ZeroMQ / OPC UA / MQTT outputs, the record file) and
    the counts of the summary."""

    def __init__(self, quiet: bool) -> None:
        self.quiet = quiet
        self.sinks: Any = None
        self.record_file: IO[str] | None = None
        self.latencies: list[float] = []
        self.frames = self.dropped = 0

    def open(self, config: Any, info: Any, wait_s: float, record_path: Path | None) -> None:
        from weldpool_core.cell.outputs import open_outputs

        if record_path is not None:
            try:
                self.record_file = record_path.open("w", encoding="utf-8")
            except OSError as exc:
                fail(
                    f"--record cannot write {str(record_path)!r} ({exc.strerror}); choose "
                    "another file."
                )
        if config.any():
            _log_to_stderr()
            self.sinks = open_outputs(config, info)
        for output in self.sinks.outputs if self.sinks else []:
            name = _OUTPUT_NAMES[output.kind]
            click.echo(f"{name} on {output.address}", err=True)
            if output.kind == "mqtt":  # the first frames are not lost to the connection
                if not output.wait_for_subscriber(max(wait_s, MQTT_CONNECT_WAIT_S)):
                    click.echo(f"{name}: no broker answers yet; publishing when it does", err=True)
            elif wait_s > 0 and not output.wait_for_subscriber(wait_s):
                click.echo(f"{name}: no subscriber after {wait_s:g} s; publishing", err=True)

    def emit(self, record: dict[str, Any]) -> None:
        line = json.dumps(record, separators=(",", ":"))
        if not self.quiet:
            sys.stdout.write(line + "\n")
            sys.stdout.flush()
        if self.sinks is not None:
            self.sinks.send(record)
        if self.record_file is not None:
            self.record_file.write(line + "\n")
        self.frames += 1
        self.dropped += record["dropped"]
        self.latencies.append(record["latency_ms"])

    def summary(self, seconds: float) -> dict[str, Any]:
        from dataclasses import asdict

        from weldpool_core.cell.stream import summary

        report = summary(self.latencies, self.frames, self.dropped, seconds)
        if self.sinks is not None:
            report["outputs"] = [asdict(status) for status in self.sinks.statuses()]
        return report

    def close(self) -> None:
        if self.sinks is not None:
            self.sinks.close()
        if self.record_file is not None:
            self.record_file.close()


MQTT_CONNECT_WAIT_S = 5.0
_OUTPUT_NAMES = {"zeromq": "ZeroMQ", "opcua": "OPC UA", "mqtt": "MQTT"}


def _log_to_stderr() -> None:
    """The outputs' problems (a broker gone, a server behind) as one line each on stderr."""
    import logging

    logger = logging.getLogger("weldpool.outputs")
    if not logger.handlers:
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("weldpool: %(message)s"))
        logger.addHandler(handler)
        logger.setLevel(logging.INFO)
        logger.propagate = False


def _status(model_dir: Path, message: str) -> None:
    click.echo(f"{model_dir}: {message} …", err=True)
