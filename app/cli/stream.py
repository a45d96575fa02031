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
from app.errors import WeldpoolError


def promoted_model_dir() -> Path:
    """The promoted student's folder in this home's database."""
    from app.storage import Storage
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
        return model_folder(Storage.of(settings), model)


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
    "--wait-for-subscriber",
    type=click.FloatRange(min=0),
    default=0.0,
    show_default=True,
    help="With --publish: seconds to wait for a subscriber before the first frame.",
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
    realtime: bool,
    max_frames: int | None,
    decoder_threads: int,
) -> None:
    """Run a student on SOURCE (a video file, a camera index such as 0, or an RTSP/HTTP URL) and
    emit one JSON line per frame: keypoints, pool area / length / width, ambiguity, latency.

    A live source keeps up by dropping stale frames (each record says how many were dropped
    before it); a file is read frame by frame unless --realtime. A summary (fps, p50 / p99
    latency) goes to stderr at the end; Ctrl-C stops cleanly.
    """
    from weldpool_core.stream import StreamOptions, open_stream

    model_dir = _checked_model_dir(model, record_path, samples, backend, sequential)
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
    )
    outputs = _Outputs(quiet)
    started = time.perf_counter()
    try:
        outputs.open(publish, wait_for_subscriber, record_path)
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


def _checked_model_dir(
    model: str, record_path: Path | None, samples: int, backend: str, sequential: bool
) -> Path:
    """The student folder to stream, after the options that cannot work together are refused."""
    if record_path is not None and not record_path.parent.is_dir():
        fail(f"There is no folder {str(record_path.parent)!r} for --record; create it first.")
    model_dir = promoted_model_dir() if model == "promoted" else Path(model)
    if not model_dir.is_dir():
        fail(f"There is no student folder {str(model_dir)!r}.")
    if samples and backend != "torch":
        fail("--samples needs --backend torch (the uncertainty draws the latent in PyTorch).")
    if samples and sequential:
        fail("--samples scores the per-frame student; leave out --sequential to use it.")
    return model_dir


def _smoothing(smooth: str, min_cutoff: float | None, beta: float | None) -> Any:
    """The One-Euro filter's settings (None: raw keypoints)."""
    from weldpool_core.smoothing import SmoothingParams

    if smooth != "one-euro":
        return None
    params = SmoothingParams()
    params = replace(params, min_cutoff=params.min_cutoff if min_cutoff is None else min_cutoff)
    return replace(params, beta=params.beta if beta is None else beta)


class _Outputs:
    """Where each record goes (stdout, the ZeroMQ publisher, the record file) and the counts
    of the summary."""

    def __init__(self, quiet: bool) -> None:
        self.quiet = quiet
        self.publisher: Any = None
        self.record_file: IO[str] | None = None
        self.latencies: list[float] = []
        self.frames = self.dropped = 0

    def open(self, publish: str | None, wait_s: float, record_path: Path | None) -> None:
        from weldpool_core.stream import Publisher

        self.publisher = Publisher(publish) if publish else None
        if (
            self.publisher is not None
            and wait_s > 0
            and not self.publisher.wait_for_subscriber(wait_s)
        ):
            click.echo(f"no subscriber after {wait_s:g} s; publishing", err=True)
        if record_path is not None:
            try:
                self.record_file = record_path.open("w", encoding="utf-8")
            except OSError as exc:
                fail(
                    f"--record cannot write {str(record_path)!r} ({exc.strerror}); choose "
                    "another file."
                )

    def emit(self, record: dict[str, Any]) -> None:
        _emit(record, self.quiet, self.publisher, self.record_file)
        self.frames += 1
        self.dropped += record["dropped"]
        self.latencies.append(record["latency_ms"])

    def summary(self, seconds: float) -> dict[str, Any]:
        from weldpool_core.stream import summary

        return summary(self.latencies, self.frames, self.dropped, seconds)

    def close(self) -> None:
        if self.publisher is not None:
            self.publisher.close()
        if self.record_file is not None:
            self.record_file.close()


def _status(model_dir: Path, message: str) -> None:
    click.echo(f"{model_dir}: {message} …", err=True)


def _emit(record: dict[str, Any], quiet: bool, publisher: Any, record_file: IO[str] | None) -> None:
    line = json.dumps(record, separators=(",", ":"))
    if not quiet:
        sys.stdout.write(line + "\n")
        sys.stdout.flush()
    if publisher is not None:
        publisher.send(record)
    if record_file is not None:
        record_file.write(line + "\n")
