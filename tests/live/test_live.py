"""Live views through the API: start on a video, read records and MJPEG frames, stop, limits."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.core.config import Settings
from app.core.models import ModelVersion, Role
from app.live.service import MAX_RUNNING, overlay_jpeg
from tests.core.student.common import TINY_STUDENT, synthetic_frames, tiny_config
from tests.helpers import auth, run_cli, wait_for, write_video
from weldpool_core.cell.stream import CapturedFrame, StreamResult
from weldpool_core.student.data import FrameGeometry
from weldpool_core.student.export import ensure_onnx
from weldpool_core.student.train import TrainResult, train_student


@pytest.fixture(scope="module")
def student_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("live") / "student-v1"
    train_student(synthetic_frames(8), folder, TINY_STUDENT, tiny_config())
    ensure_onnx(folder)
    return folder


def _promote(session_factory, folder: Path, home: Path) -> None:
    """The trained student as this home's promoted version (stored under models/, as training
    leaves it)."""
    shutil.copytree(folder, home / "models" / "student-v1")
    with session_factory() as session:
        session.add(
            ModelVersion(name="student-v1", checkpoint_path="models/student-v1", is_promoted=True)
        )
        session.commit()


def _wait_state(client: TestClient, view_id: int, token: str, states: set[str]) -> dict:
    found = wait_for(
        lambda: (
            (v := client.get(f"/api/v1/live/{view_id}", headers=auth(token)).json())["state"]
            in states
            and v
        ),
        timeout=60,
    )
    assert found, client.get(f"/api/v1/live/{view_id}", headers=auth(token)).json()
    return found


def test_a_live_view_streams_a_video_to_its_end(
    client: TestClient,
    make_user,
    session_factory,
    settings: Settings,
    student_dir: Path,
    tmp_path: Path,
) -> None:
    _, token = make_user("cell", Role.reviewer)
    _, annotator = make_user("ann")
    video = str(write_video(tmp_path / "run.avi", 30, fps=30.0))
    none = client.post("/api/v1/live", json={"source": video}, headers=auth(token))
    assert none.status_code == 409 and "No student is promoted" in none.json()["detail"]
    _promote(session_factory, student_dir, settings.home)
    absent = {"source": str(tmp_path / "x.mp4")}
    missing = client.post("/api/v1/live", json=absent, headers=auth(token))
    assert missing.status_code == 400 and "no video file" in missing.json()["detail"]
    refused = client.post("/api/v1/live", json={"source": video}, headers=auth(annotator))
    assert refused.status_code == 403
    started = client.post(
        "/api/v1/live", json={"source": video, "mm_per_px": 0.1}, headers=auth(token)
    )
    assert started.status_code == 201, started.text
    view = started.json()
    assert (view["model_name"], view["started_by"]) == ("student-v1", "cell")
    done = _wait_state(client, view["id"], token, {"ended", "failed"})
    assert done["state"] == "ended", done["message"]
    assert done["frames"] + done["dropped"] == 30 and done["frames"] > 0
    assert done["fps"] > 0 and done["latency_p99_ms"] >= done["latency_p50_ms"] > 0
    records = client.get(
        f"/api/v1/live/{view['id']}/records?after=-1", headers=auth(annotator)
    ).json()["records"]
    assert len(records) == done["frames"]
    assert [r["frame"] for r in records] == sorted({r["frame"] for r in records})
    assert records[-1] == done["last"] and records[0]["length_mm"] is not None
    later = client.get(
        f"/api/v1/live/{view['id']}/records?after={records[4]['frame']}", headers=auth(token)
    ).json()["records"]
    assert later == records[5:]
    # An ended view's MJPEG stream holds its last drawn frame, then ends.
    mjpeg = client.get(f"/api/v1/live/{view['id']}/mjpeg", headers=auth(token))
    assert mjpeg.headers["content-type"].startswith("multipart/x-mixed-replace")
    body = mjpeg.content
    jpeg = body[body.index(b"\xff\xd8") : body.rindex(b"\xff\xd9") + 2]
    assert cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR).shape == (64, 96, 3)
    listed = client.get("/api/v1/live", headers=auth(token)).json()
    assert [v["id"] for v in listed] == [view["id"]]
    assert client.get("/api/v1/live/999", headers=auth(token)).status_code == 404


def test_live_views_stop_on_request_and_are_limited(
    client: TestClient,
    make_user,
    session_factory,
    settings: Settings,
    student_dir: Path,
    tmp_path: Path,
) -> None:
    _, token = make_user("cell", Role.reviewer)
    _promote(session_factory, student_dir, settings.home)
    long_video = str(write_video(tmp_path / "long.avi", 300, fps=20.0))  # 15 s at its rate
    ids = []
    for _ in range(MAX_RUNNING):
        response = client.post("/api/v1/live", json={"source": long_video}, headers=auth(token))
        assert response.status_code == 201
        ids.append(response.json()["id"])
    extra = client.post("/api/v1/live", json={"source": long_video}, headers=auth(token))
    assert extra.status_code == 409 and "stop one" in extra.json()["detail"]
    _wait_state(client, ids[0], token, {"running"})
    stopped = client.post(f"/api/v1/live/{ids[0]}/stop", headers=auth(token)).json()
    assert stopped["state"] == "stopped" and stopped["frames"] + stopped["dropped"] < 300
    again = client.post("/api/v1/live", json={"source": long_video}, headers=auth(token))
    assert again.status_code == 201  # a slot is free again
    for view_id in (ids[1], again.json()["id"]):
        assert client.post(f"/api/v1/live/{view_id}/stop", headers=auth(token)).status_code == 200


def test_the_overlay_draws_the_mask_and_keypoints_where_they_are_in_the_frame() -> None:
    """A 1920×1200 frame shown 960 wide: the outline and the keypoint land at half the frame's
    coordinates (a lost scale or swapped axis misses them)."""
    geometry = FrameGeometry.fit(1200, 1920, 64, "letterbox")  # inner 64×40, offset y 12
    mask = np.zeros((64, 64), np.float32)
    mask[22:42, 16:48] = 1.0  # frame x 480..1439, y 300..899
    frame = CapturedFrame(0, 0.0, 0.0, np.zeros((1200, 1920, 3), np.uint8))
    keypoint = [1500.0, 300.0]
    result = StreamResult({}, frame, mask, geometry, [keypoint, None])
    shown = cv2.imdecode(np.frombuffer(overlay_jpeg(result), np.uint8), cv2.IMREAD_COLOR)
    assert shown.shape == (600, 960, 3)
    bright = shown.max(axis=2) > 100
    assert bright[450, 236:244].any() and bright[450, 716:724].any()  # left and right edges
    assert bright[146:154, 480].any() and not bright[300, 480]  # top edge; inside stays dark
    red = (shown[:, :, 2] > 150) & (shown[:, :, 1] < 100)
    ys, xs = np.nonzero(red)
    assert abs(xs.mean() - 750) < 3 and abs(ys.mean() - 150) < 3


def test_weldpool_stream_runs_this_homes_promoted_student(
    client: TestClient, session_factory, settings: Settings, student_dir: Path, tmp_path: Path
) -> None:
    video = str(write_video(tmp_path / "run.avi", 5))
    env = {
        "WELDPOOL_HOME": str(settings.home),
        "WELDPOOL_DATABASE_URL": settings.resolved_database_url,
    }
    none = run_cli("stream", video, env=env)
    assert none.returncode == 2
    assert none.stderr.strip().splitlines()[-1] == (
        "weldpool: No student is promoted yet; train and promote one, or give --model MODEL_DIR."
    )
    _promote(session_factory, student_dir, settings.home)
    with session_factory() as session:  # promoted by force over the gate's verdict
        session.execute(
            sa.update(ModelVersion).values(
                gate={"usable": False, "reason": "worse than the teacher on 3 held-out frames"}
            )
        )
        session.commit()
    ran = run_cli("stream", video, "--max-frames", "3", "--smooth", "none", env=env)
    assert ran.returncode == 0, ran.stderr
    assert ran.stderr.splitlines()[0] == (
        "weldpool: warning: student-v1 is not usable by the promotion gate (worse than the "
        "teacher on 3 held-out frames); its masks may be worse than the teacher's."
    )
    records = [json.loads(line) for line in ran.stdout.splitlines()]
    assert [r["frame"] for r in records] == [0, 1, 2]
    assert all(r["keypoints_raw"] is None for r in records)  # no smoothing asked for
    assert json.loads(ran.stderr.strip().splitlines()[-1])["model"].endswith("models/student-v1")


def test_weldpool_stream_records_only_into_a_folder_that_exists(
    student_dir: Path, tmp_path: Path
) -> None:
    """--record into a missing folder: one line on stderr and exit 2, before any frame is read
    (not a traceback once the student has loaded)."""
    video = str(write_video(tmp_path / "run.avi", 3))
    record = tmp_path / "missing" / "run.jsonl"
    ran = run_cli("stream", video, "--model", student_dir, "--record", record, "--quiet")
    assert ran.returncode == 2, ran.stderr
    assert ran.stderr.splitlines() == [
        f"weldpool: There is no folder {str(record.parent)!r} for --record; create it first."
    ]
    assert not record.parent.exists()


def test_only_the_newest_ended_views_are_kept(tmp_path: Path) -> None:
    """A long-running server does not keep every view it ever ran: the 20 newest ended ones."""
    from app.live.service import KEEP_ENDED, LiveView, LiveViews

    views = LiveViews()
    args = {
        "source": str(write_video(tmp_path / "run.avi", 2)),
        "model_name": "gone",
        "model_dir": tmp_path / "no-such-model",
        "started_by": "cell",
        "smooth": False,
        "mm_per_px": None,
        "travel_deg": None,
    }
    for view_id in range(1, 26):
        views._views[view_id] = LiveView(id=view_id, state="ended", **args)
    views._ids = iter(range(26, 100))
    started = views.start(args)
    kept = [view.id for view in views.all()]
    assert started.id in kept and len(kept) == KEEP_ENDED + 1
    assert min(kept) == 26 - KEEP_ENDED  # the oldest went first
    assert wait_for(lambda: started.state == "failed", timeout=60)  # no such model folder
    assert started.message.endswith(
        "is not a student model folder (config.json is missing); train a student into it first."
    )


def test_a_sequential_cell_learns_from_video_labels_is_measured_and_runs_live(
    client: TestClient,
    make_user,
    session_factory,
    settings: Settings,
    student_dir: Path,
    tmp_path: Path,
) -> None:
    """From the models page's button to a live view: the cell trains on the training split's
    reviewed video frames (decoding the stored video at its own rate), is measured on the
    validation split's against the per-frame student, and a live view runs it."""
    from app.core.models import Frame, Split
    from tests.helpers import corrected_label, wait_for_job
    from weldpool_core.synth import SynthParams, synth_frame

    _, token = make_user("cell", Role.reviewer)
    _promote(session_factory, student_dir, settings.home)
    unlabelled = client.post("/api/v1/models/1/sequential", json={}, headers=auth(token))
    assert unlabelled.status_code == 400 and "imported video" in unlabelled.json()["detail"]
    path = write_video(tmp_path / "run.avi", 30, fps=30.0)
    with open(path, "rb") as handle:
        uploaded = client.post(
            "/api/v1/videos",
            files={"file": ("run.avi", handle, "video/avi")},
            data={"every_nth": "5"},
            headers=auth(token),
        ).json()
    assert wait_for_job(client, uploaded["job_id"], token, timeout=60)["status"] == "succeeded"
    with session_factory() as session:
        frames = {f.frame_index: f.id for f in session.query(Frame).all()}
        session.get_one(Frame, frames[25]).split = Split.validation
        session.commit()
    assert sorted(frames) == [0, 5, 10, 15, 20, 25]
    for index in (10, 20, 25):  # write_video draws synthetic run index % 3
        mask = synth_frame(index % 3, SynthParams(width=96, height=64)).mask
        saved = client.put(
            f"/api/v1/frames/{frames[index]}/label", json=corrected_label(mask), headers=auth(token)
        )
        assert saved.status_code == 200, saved.text
    started = client.post("/api/v1/models/1/sequential", json={"steps": 10}, headers=auth(token))
    assert started.status_code == 202, started.text
    again = client.post("/api/v1/models/1/sequential", json={}, headers=auth(token))
    assert again.status_code == 409 and "already training" in again.json()["detail"]
    job = wait_for_job(client, started.json()["job_id"], token, timeout=240)
    assert job["status"] == "succeeded", job
    record = client.get("/api/v1/models/1", headers=auth(token)).json()["sequential"]
    # Label 10 makes one window (stride 1: frames 3–10), label 20 two (strides 1 and 2); the
    # validation frame 25 is measured, never trained on.
    assert (record["windows"], record["videos"], record["steps"]) == (3, 1, 10)
    # Unlabelled windows end at frames 7..29, alternately learned from and measured on; those
    # that hold the validation frame 25 (ends 25, 27, 29) are not learned from: 11 measured.
    measured = record["measured"]
    assert (measured["frames"], measured["windows"]) == (1, 11)
    for key in ("per_frame_iou", "sequential_iou", "per_frame_change", "sequential_change"):
        assert 0.0 <= measured[key] <= 1.0, (key, measured)
    assert job["message"] == (
        f"student-v1: sequential cell trained on 3 windows; mask IoU "
        f"{measured['sequential_iou']:.3f} against the per-frame {measured['per_frame_iou']:.3f} "
        f"on 1 validation frame; the mask changes {100 * measured['sequential_change']:.1f} % "
        f"per frame against {100 * measured['per_frame_change']:.1f} %"
    )
    cell = settings.home / "models" / "student-v1" / "sequential.safetensors"
    kept = cell.read_bytes()

    # A job that fails after writing its cell puts the version's cell back, record unchanged.
    import weldpool_core.student.sequential as sequential_module

    def broken(*_args: object, **_kwargs: object) -> dict:
        raise RuntimeError("the measurement broke")

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(sequential_module, "measure_sequential", broken)
        failing = client.post(
            "/api/v1/models/1/sequential", json={"steps": 3, "seed": 1}, headers=auth(token)
        )
        assert wait_for_job(client, failing.json()["job_id"], token, 240)["status"] == "failed"
    assert cell.read_bytes() == kept
    assert client.get("/api/v1/models/1", headers=auth(token)).json()["sequential"] == record

    # A frame the version trained on, moved to the validation split since, is not measured.
    with session_factory() as session:
        session.get_one(ModelVersion, 1).train_frame_ids = [frames[25]]
        session.commit()
    excluded = client.post("/api/v1/models/1/sequential", json={"steps": 3}, headers=auth(token))
    job = wait_for_job(client, excluded.json()["job_id"], token, timeout=240)
    assert job["status"] == "succeeded", job
    remeasured = client.get("/api/v1/models/1", headers=auth(token)).json()["sequential"]
    assert remeasured["measured"]["frames"] == 0
    assert remeasured["measured"]["per_frame_iou"] is None
    assert "no validation frame of a video to measure its accuracy on" in job["message"]

    live = client.post(
        "/api/v1/live", json={"source": str(path), "sequential": True}, headers=auth(token)
    )
    assert live.status_code == 201, live.text
    assert live.json()["sequential"] is True
    done = _wait_state(client, live.json()["id"], token, {"ended", "failed"})
    assert done["state"] == "ended" and done["frames"] > 0, done["message"]
    with session_factory() as session:
        session.add(ModelVersion(name="student-v2", checkpoint_path="models/student-v1"))
        session.commit()
    plain = {"source": str(path), "sequential": True, "model_id": 2}
    refused = client.post("/api/v1/live", json=plain, headers=auth(token))
    assert refused.status_code == 400 and "no sequential cell" in refused.json()["detail"]
    with session_factory() as session:
        session.add(ModelVersion(name="student-v3", checkpoint_path="models/gone"))
        session.commit()
    weightless = client.post("/api/v1/models/3/sequential", json={}, headers=auth(token))
    assert weightless.status_code == 409
    assert weightless.json()["detail"] == "student-v3 has no weights on this server."
    assert (
        client.post("/api/v1/models/9/sequential", json={}, headers=auth(token)).status_code == 404
    )

    # The stored video went missing: the job says which, in one sentence.
    for stored in (settings.home / "videos").rglob("*.avi"):
        stored.unlink()
    lost = client.post("/api/v1/models/1/sequential", json={"steps": 3}, headers=auth(token))
    job = wait_for_job(client, lost.json()["job_id"], token, timeout=240)
    assert job["status"] == "failed"
    assert job["error"] == "The stored file of video run.avi is missing; import it again."


def test_an_int8_student_is_made_from_the_projects_frames_recorded_and_runs_live(
    client: TestClient,
    make_user,
    session_factory,
    settings: Settings,
    tmp_path: Path,
    sure_student: TrainResult,
) -> None:
    """The models page's "Make int8": calibrated on the project's frames, checked against the
    float student, recorded on the version with both speeds; a failed record puts the earlier
    file back; the live view runs it, only for a version that has one and not with sequential.
    The student is the run's ``sure_student`` (trained long enough for crisp masks: int8 can
    match it), copied into this home."""
    from tests.helpers import wait_for_job
    from weldpool_core.student.checkpoint import INT8_ONNX_FILE
    from weldpool_core.synth import SynthParams, synth_frame

    _, token = make_user("cell", Role.reviewer)
    _promote(session_factory, sure_student.model_dir, settings.home)
    video = str(write_video(tmp_path / "run.avi", 20, fps=30.0))
    early = client.post("/api/v1/models/1/int8", headers=auth(token))
    assert early.status_code == 400 and "at least 4 frames" in early.json()["detail"]
    params = SynthParams(width=96, height=64)
    files = [
        ("files", (f"c{s}.png", cv2.imencode(".png", synth_frame(s, params).image)[1].tobytes()))
        for s in range(100, 112)
    ]
    assert client.post("/api/v1/frames", files=files, headers=auth(token)).status_code == 201
    unmade = client.post("/api/v1/live", json={"source": video, "int8": True}, headers=auth(token))
    assert unmade.status_code == 400 and "has no int8 student" in unmade.json()["detail"]

    # What a worker killed while quantizing leaves behind is cleared by the next job; another
    # writer's temporaries (a live view exporting model.onnx) are not the job's to remove.
    folder = settings.home / "models" / "student-v1"
    (folder / ".quantize.k1ll3d").mkdir()
    (folder / ".quantize.k1ll3d" / "prepared.onnx").write_bytes(b"half")
    for name in (f".{INT8_ONNX_FILE}.x1", ".model.onnx.x2", ".export.json.x3"):
        (folder / name).write_bytes(b"half")
    started = client.post("/api/v1/models/1/int8", headers=auth(token))
    assert started.status_code == 202, started.text
    job = wait_for_job(client, started.json()["job_id"], token, timeout=120)
    assert job["status"] == "succeeded", job
    assert sorted(p.name for p in folder.glob(".*")) == [".export.json.x3", ".model.onnx.x2"]
    record = client.get("/api/v1/models/1", headers=auth(token)).json()["int8"]
    assert (record["calibration_frames"], record["check_frames"]) == (6, 6)
    assert record["mean_iou"] >= 0.97 and record["job_id"] == job["id"]
    assert record["float_ms"] > 0 and record["int8_ms"] > 0
    assert job["message"].startswith(
        f"student-v1: int8 student made; masks agree with the float student's at IoU "
        f"{record['mean_iou']:.3f}"
    )
    made = settings.home / "models" / "student-v1" / INT8_ONNX_FILE
    kept = made.read_bytes()

    # A job whose record cannot be written puts the earlier int8 file and export.json back
    # (this one writes other bytes first, so a missing put-back shows), record unchanged.
    import app.training.tasks as tasks_module
    import weldpool_core.student.quantize as quantize_module

    exported = made.parent / "export.json"
    before = exported.read_bytes()
    real = quantize_module.quantize_student

    def other_bytes(*args: object, **kwargs: object) -> object:
        result = real(*args, **kwargs)  # type: ignore[arg-type]
        made.write_bytes(b"another int8 file")
        exported.write_text("{}")
        return result

    def broken(*_args: object, **_kwargs: object) -> str:
        raise RuntimeError("the clock broke")

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(quantize_module, "quantize_student", other_bytes)
        patch.setattr(tasks_module, "utcnow", broken)
        failing = client.post("/api/v1/models/1/int8", headers=auth(token))
        assert wait_for_job(client, failing.json()["job_id"], token, 120)["status"] == "failed"
    assert made.read_bytes() == kept and exported.read_bytes() == before
    assert client.get("/api/v1/models/1", headers=auth(token)).json()["int8"] == record

    both = {"source": video, "int8": True, "sequential": True}
    mixed = client.post("/api/v1/live", json=both, headers=auth(token))
    assert mixed.status_code == 400 and "choose int8 or sequential" in mixed.json()["detail"]
    live = client.post("/api/v1/live", json={"source": video, "int8": True}, headers=auth(token))
    assert live.status_code == 201, live.text
    ended = _wait_state(client, live.json()["id"], token, {"ended", "failed"})
    assert ended["state"] == "ended" and ended["int8"] is True, ended
    assert ended["frames"] + ended["dropped"] == 20 and ended["last"]["area_px"] > 0


@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)  # outputs touch no SQL
def test_a_live_view_serves_opcua_and_publishes_mqtt_and_shows_their_counts(
    client: TestClient,
    make_user,
    session_factory,
    settings: Settings,
    student_dir: Path,
    tmp_path: Path,
    request: pytest.FixtureRequest,
) -> None:
    """The view's outputs from the form: an OPC UA client's subscription and the frames sent
    show on the view; a port in use is a 400 and takes no slot."""
    import asyncio

    from asyncua import Client

    from tests.mqtt import Listener, free_port, start_broker, unique_topic

    _, token = make_user("cell", Role.reviewer)
    _promote(session_factory, student_dir, settings.home)
    broker, port = start_broker(tmp_path)  # its own, so no other test's messages are seen
    request.addfinalizer(broker.terminate)
    listener = Listener("127.0.0.1", port, unique_topic("live"))
    opc_port = free_port()
    video = str(write_video(tmp_path / "long.avi", 200, fps=20.0))
    body = {
        "source": video,
        "opcua": f"opc.tcp://127.0.0.1:{opc_port}",
        "mqtt": listener.url,
    }
    for field, value, words in (  # within what the admin allows, and nothing else
        ("zeromq", f"ipc://{settings.home}/weldpool.db", "tcp://HOST:PORT only"),
        ("zeromq", "tcp://0.0.0.0:5556", "may not listen on 0.0.0.0"),
        ("opcua", "opc.tcp://0.0.0.0:4840", "WELDPOOL_LIVE_BIND_HOSTS: 127.0.0.1"),
        ("opcua", "opc.tcp://127.0.0.1:502", "port must be 1024 or above"),
        ("mqtt", "mqtt://10.1.2.3:1883/cell/live", "may not publish to the broker 10.1.2.3"),
        ("mqtt", "mqtt://u:hunter2@127.0.0.1", "needs a topic"),
    ):
        refused = client.post(
            "/api/v1/live", json={"source": video, field: value}, headers=auth(token)
        )
        assert refused.status_code == 400 and words in refused.json()["detail"], refused.text
        assert "hunter2" not in refused.text
    assert client.get("/api/v1/live", headers=auth(token)).json() == []  # none took a slot
    started = client.post("/api/v1/live", json=body, headers=auth(token))
    assert started.status_code == 201, started.text
    view_id = started.json()["id"]
    busy = client.post("/api/v1/live", json=body | {"mqtt": None}, headers=auth(token))
    assert busy.status_code == 400 and "the port is in use" in busy.json()["detail"]

    class Handler:
        def datachange_notification(self, *_args: object) -> None:
            pass

    async def subscribed() -> dict:
        async with Client(f"opc.tcp://127.0.0.1:{opc_port}/weldpool/") as opc:
            index = await opc.get_namespace_index("urn:weldpool:stream")
            subscription = await opc.create_subscription(50, Handler())
            await subscription.subscribe_data_change(opc.get_node(f"ns={index};s=WeldPool.Width"))
            found = wait_for(
                lambda: (
                    (v := client.get(f"/api/v1/live/{view_id}", headers=auth(token)).json())
                    and v["outputs"][0]["subscribers"] == 1
                    and v["outputs"][1]["sent"] > 0
                    and v
                ),
                timeout=30,
            )
            return found

    try:
        view = asyncio.run(subscribed())
        listener.wait_for(lambda: len(listener.frames(listener.topic)) > 0)
    finally:
        client.post(f"/api/v1/live/{view_id}/stop", headers=auth(token))
        listener.close()
    kinds = [(o["kind"], o["state"]) for o in view["outputs"]]
    assert kinds == [("opcua", "serving"), ("mqtt", "connected")]
    assert view["outputs"][1]["subscribers"] is None
    assert listener.frames(listener.topic)[0]["frame"] >= 0
    ended = client.get(f"/api/v1/live/{view_id}", headers=auth(token)).json()
    assert ended["outputs"][0]["state"] == "stopped"
    again = client.post("/api/v1/live", json=body | {"mqtt": None}, headers=auth(token))
    assert again.status_code == 201  # the stopped view let its port go
    client.post(f"/api/v1/live/{again.json()['id']}/stop", headers=auth(token))


def test_an_admin_opens_the_cells_network_to_the_live_views_outputs(settings: Settings) -> None:
    from app.core.errors import InvalidInputError
    from app.live.service import check_outputs

    opened = settings.model_copy(
        update={"live_bind_hosts": "0.0.0.0", "live_mqtt_brokers": "broker"}
    )
    check_outputs("tcp://0.0.0.0:5556", "opc.tcp://0.0.0.0:4840", "mqtt://broker/c/p", opened)
    closed = settings.model_copy(update={"live_bind_hosts": "", "live_mqtt_brokers": ""})
    with pytest.raises(InvalidInputError, match="BIND_HOSTS: none"):
        check_outputs(None, "opc.tcp://127.0.0.1:4840", None, closed)
    with pytest.raises(InvalidInputError, match="BROKERS: none"):
        check_outputs(None, None, "mqtt://127.0.0.1/c/p", closed)
