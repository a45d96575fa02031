"""Frame upload through the REST API, on SQLite and PostgreSQL: storage, refusals, duplicates,
limits and atomicity."""

from __future__ import annotations

import hashlib
import io
from pathlib import Path
from typing import Any

import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient
from PIL import Image

from app.core.config import Settings
from app.core.housekeeping import FileCollector, sweep_orphan_files
from app.core.models import DoomedFile, Frame, Role
from app.frames import deletion, ingest, listing, sequences
from app.main import create_app
from app.storage import LocalStorage
from app.storage import local as storage_module
from tests.helpers import age_stored_files, auth, image_bytes, wait_for


@pytest.fixture
def token(make_user) -> str:
    return make_user("uploader", Role.annotator)[1]


def _sequence(client: TestClient, token: str, name: str = "run-1", **params) -> int:
    response = client.post("/api/v1/sequences", json={"name": name, **params}, headers=auth(token))
    assert response.status_code == 201, response.text
    return int(response.json()["id"])


def _upload(client: TestClient, token: str, files: list[tuple[str, bytes]], **data):
    parts = [("files", (name, content, "application/octet-stream")) for name, content in files]
    return client.post("/api/v1/frames", files=parts, data=data, headers=auth(token))


def _stored_files(settings: Settings) -> list[Path]:
    root = settings.home / "frames"
    return [p for p in root.rglob("*") if p.is_file()] if root.exists() else []


def _staged_files(settings: Settings) -> list[Path]:
    """Temporaries of files staged for a request (``Storage.stage``) and not installed."""
    root = settings.home / "tmp"
    return sorted(root.glob("*")) if root.exists() else []


def _bomb() -> bytes:
    buffer = io.BytesIO()
    Image.new("1", (20000, 20000)).save(buffer, "PNG")
    return buffer.getvalue()


def test_sequence_with_process_parameters(client: TestClient, token: str) -> None:
    params = {
        "wire_feed_m_min": 8.5,
        "voltage_v": 24.1,
        "current_a": 190.0,
        "arc_length_correction_pct": -5.0,
        "robot_speed_cm_min": 45.0,
        "joint_type": "fillet",
        "notes": "Tee joint, CMT",
    }
    sequence_id = _sequence(client, token, "run-A", **params)
    body = client.get(f"/api/v1/sequences/{sequence_id}", headers=auth(token)).json()
    assert body == body | params | {"frame_count": 0}
    again = client.post("/api/v1/sequences", json={"name": "run-A"}, headers=auth(token))
    assert again.status_code == 409
    assert again.json()["detail"] == "There is already a sequence named 'run-A'."
    bad = client.post("/api/v1/sequences", json={"name": "x", "voltage_v": -3}, headers=auth(token))
    assert bad.status_code == 422 and bad.json()["detail"].startswith("voltage_v:")
    patched = client.patch(
        f"/api/v1/sequences/{sequence_id}", json={"notes": "synergic"}, headers=auth(token)
    )
    assert patched.json()["notes"] == "synergic" and patched.json()["voltage_v"] == 24.1


def test_batch_of_every_supported_kind(client: TestClient, token: str, settings: Settings):
    sequence_id = _sequence(client, token)
    files = [
        ("gray8.png", image_bytes(seed=1)),
        ("gray16.png", image_bytes(seed=2, bit_depth=16)),
        ("rgba.png", image_bytes(seed=3, channels=4)),
        ("color.jpg", image_bytes(seed=4, channels=3, fmt=".jpg")),
        ("gray16.tif", image_bytes(seed=5, bit_depth=16, fmt=".tif")),
        ("color.bmp", image_bytes(seed=6, channels=3, fmt=".bmp")),
    ]
    response = _upload(client, token, files, sequence_id=str(sequence_id))
    assert response.status_code == 201, response.text
    body = response.json()
    assert body["rejected"] == [] and body["duplicates"] == []
    stored = {f["original_name"]: f for f in body["stored"]}
    assert stored["gray16.png"] == stored["gray16.png"] | {
        "bit_depth": 16,
        "channels": 1,
        "media_type": "image/png",
    }
    assert stored["rgba.png"]["channels"] == 4
    assert stored["color.jpg"]["media_type"] == "image/jpeg"
    assert stored["gray16.tif"] == stored["gray16.tif"] | {
        "bit_depth": 16,
        "media_type": "image/tiff",
    }
    assert all(f["width"] == 64 and f["height"] == 48 for f in body["stored"])
    for name, content in files:
        frame = stored[name]
        assert frame["sha256"] == hashlib.sha256(content).hexdigest()
        original = client.get(f"/api/v1/frames/{frame['id']}/image", headers=auth(token))
        assert original.content == content  # stored untouched
        assert original.headers["content-type"] == frame["media_type"]
    display = client.get(
        f"/api/v1/frames/{stored['gray16.png']['id']}/image",
        params={"variant": "display"},
        headers=auth(token),
    )
    shown = Image.open(io.BytesIO(display.content))
    assert shown.mode == "L" and shown.size == (64, 48)
    thumb = client.get(
        f"/api/v1/frames/{stored['color.bmp']['id']}/image",
        params={"variant": "thumb"},
        headers=auth(token),
    )
    assert Image.open(io.BytesIO(thumb.content)).mode == "RGB"
    # Files are named by content, never by the client's name.
    suffix = {"image/png": ".png", "image/jpeg": ".jpg", "image/tiff": ".tif", "image/bmp": ".bmp"}
    names = {p.name for p in _stored_files(settings)}
    assert names == {f["sha256"] + suffix[f["media_type"]] for f in stored.values()}
    health = client.get("/api/v1/health").json()  # usable; degraded only by the absent teacher
    assert health["status"] == "degraded" and health["warnings"][0].startswith("The teacher")


def test_mixed_batch_stores_the_good_and_names_each_refusal(
    client: TestClient, token: str, settings: Settings
) -> None:
    good = [("a.png", image_bytes(seed=10)), ("b.png", image_bytes(seed=11))]
    bad = [
        ("empty.png", b""),
        ("notes.png", b"just some text, not an image"),
        ("cut.png", image_bytes(seed=12)[:200]),
        ("drawing.svg", b'<svg xmlns="http://www.w3.org/2000/svg"><rect/></svg>'),
        ("page.png", b"<!doctype html><html><script>alert(1)</script></html>"),
        ("bomb.png", _bomb()),
        ("../../etc/evil.png", image_bytes(seed=13)),
        ("dir\\evil.png", image_bytes(seed=14)),
        ("C:\\Windows\\evil.png", image_bytes(seed=15)),  # the parser alone keeps "evil.png"
    ]
    response = _upload(client, token, good[:1] + bad + good[1:])
    assert response.status_code == 201
    body = response.json()
    assert [f["original_name"] for f in body["stored"]] == ["a.png", "b.png"]
    reasons = {r["name"]: r["reason"] for r in body["rejected"]}
    assert reasons["empty.png"] == "The file is empty."
    assert "not a readable image" in reasons["notes.png"]
    assert "truncated" in reasons["cut.png"]
    assert "SVG images are not supported" in reasons["drawing.svg"]
    assert "HTML files are not images" in reasons["page.png"]
    assert "more than the limit" in reasons["bomb.png"]
    assert "path parts" in reasons["../../etc/evil.png"]
    assert "path parts" in reasons["dir\\evil.png"]
    assert "path parts" in reasons["C:\\Windows\\evil.png"]
    assert len(_stored_files(settings)) == 2  # nothing of the refused files was written
    assert not list(settings.home.parent.rglob("evil.png"))
    assert client.get("/api/v1/frames", headers=auth(token)).json()["total"] == 2


def test_all_refused_is_422_with_a_sentence(client: TestClient, token: str, settings) -> None:
    response = _upload(client, token, [("x.gif", b"GIF89a\x01\x00\x01\x00\x00\x00\x00;")])
    assert response.status_code == 422
    assert response.json()["detail"].startswith("No frame was stored; x.gif: ")
    assert _stored_files(settings) == []


def test_duplicates_are_reported_not_stored_twice(
    client: TestClient, token: str, settings: Settings
) -> None:
    first_run, second_run = _sequence(client, token, "one"), _sequence(client, token, "two")
    content = image_bytes(seed=20)
    response = _upload(
        client, token, [("x.png", content), ("copy.png", content)], sequence_id=str(first_run)
    )
    body = response.json()
    assert len(body["stored"]) == 1
    frame_id = body["stored"][0]["id"]
    assert body["duplicates"] == [
        {"name": "copy.png", "sha256": body["stored"][0]["sha256"], "frame_id": frame_id}
    ]
    again = _upload(client, token, [("x.png", content)], sequence_id=str(first_run))
    assert again.status_code == 200
    assert again.json()["duplicates"][0]["frame_id"] == frame_id
    elsewhere = _upload(client, token, [("x.png", content)], sequence_id=str(second_run))
    assert elsewhere.status_code == 201  # another run may hold the same content…
    assert len(_stored_files(settings)) == 1  # …sharing one file
    loose = [_upload(client, token, [("x.png", content)]) for _ in range(2)]
    assert [r.status_code for r in loose] == [201, 200]  # also deduplicated without sequence


def test_copies_in_one_request_are_checked_once(
    client: TestClient, token: str, monkeypatch
) -> None:
    import app.frames.ingest as frames_service

    decoded: list[int] = []
    real = frames_service.check_image

    def counting(data, *args, **kwargs):  # type: ignore[no-untyped-def]
        decoded.append(len(data))
        return real(data, *args, **kwargs)

    monkeypatch.setattr(frames_service, "check_image", counting)
    content, broken = image_bytes(seed=21), image_bytes(seed=22)[:150]
    files = [(f"copy{i}.png", content) for i in range(8)] + [("../bad-name.png", content)]
    files += [(f"cut{i}.png", broken) for i in range(3)] + [("other.png", image_bytes(seed=23))]
    body = _upload(client, token, files).json()
    assert sorted(decoded) == sorted([len(content), len(broken), len(files[-1][1])])
    assert [f["original_name"] for f in body["stored"]] == ["copy0.png", "other.png"]
    assert [d["name"] for d in body["duplicates"]] == [f"copy{i}.png" for i in range(1, 8)]
    reasons = {r["name"]: r["reason"] for r in body["rejected"]}
    assert "path parts" in reasons["../bad-name.png"]
    assert {reasons[f"cut{i}.png"] for i in range(3)} == {reasons["cut0.png"]}
    assert "truncated" in reasons["cut0.png"]


def test_a_request_refused_after_its_files_were_staged_leaves_nothing(
    client: TestClient, token: str, settings: Settings, make_user
) -> None:
    """Files are checked and staged on disk while the body arrives; a request refused after
    that (its run unknown, a bad field, too many files, a body cut short) leaves no file."""
    good = [(f"{i}.png", image_bytes(seed=90 + i)) for i in range(3)]
    missing = _upload(client, token, good, sequence_id="999")
    assert missing.status_code == 404
    not_int = _upload(client, token, good, sequence_id="seven")
    assert not_int.status_code == 400 and "integer" in not_int.json()["detail"]
    body = b"".join(
        b'--x\r\nContent-Disposition: form-data; name="files"; filename="%d.png"\r\n\r\n%s\r\n'
        % (i, data)
        for i, (_, data) in enumerate(good)
    )
    cut = client.post(
        "/api/v1/frames",
        content=body + b"--x\r\nContent-Disp",  # no closing boundary
        headers=auth(token) | {"content-type": "multipart/form-data; boundary=x"},
    )
    assert cut.status_code == 400 and cut.json()["detail"].endswith(".")
    _, other = make_user("few", Role.annotator)
    few = settings.model_copy(update={"max_files_per_request": 2})
    with TestClient(create_app(few)) as limited:
        too_many = _upload(limited, other, good)
        assert too_many.status_code == 400
        assert "WELDPOOL_MAX_FILES_PER_REQUEST" in too_many.json()["detail"]
    assert _stored_files(settings) == [] and _staged_files(settings) == []
    assert _upload(client, token, good).status_code == 201
    assert len(_stored_files(settings)) == 3 and _staged_files(settings) == []


def test_request_over_the_size_limit_is_413(
    tmp_path: Path, settings: Settings, session_factory, make_user
) -> None:
    _, token = make_user("big", Role.annotator)
    small = settings.model_copy(update={"max_request_mb": 0.05})  # 51 kB
    big = image_bytes(200, 200, seed=30, channels=3)  # ~120 kB of noise
    with TestClient(create_app(small)) as client:
        response = _upload(client, token, [("big.png", big)])
        assert response.status_code == 413
        assert "WELDPOOL_MAX_REQUEST_MB" in response.json()["detail"]

        def chunks():  # no Content-Length: the limit applies while streaming
            yield b'--x\r\nContent-Disposition: form-data; name="files"; filename="a.png"'
            yield b"\r\n\r\n" + big + b"\r\n--x--\r\n"

        streamed = client.post(
            "/api/v1/frames",
            content=chunks(),
            headers=auth(token) | {"content-type": "multipart/form-data; boundary=x"},
        )
        assert streamed.status_code == 413
        assert client.get("/api/v1/health").status_code == 200
        ok = _upload(client, token, [("small.png", image_bytes(seed=31))])
        assert ok.status_code == 201
    assert len(_stored_files(small)) == 1


def test_bad_requests(client: TestClient, token: str) -> None:
    missing = _upload(client, token, [("a.png", image_bytes())], sequence_id="999")
    assert missing.status_code == 404 and missing.json()["detail"] == "There is no sequence 999."
    not_int = _upload(client, token, [("a.png", image_bytes())], sequence_id="seven")
    assert not_int.status_code == 400
    as_json = client.post("/api/v1/frames", json={"files": []}, headers=auth(token))
    assert as_json.status_code == 400
    assert as_json.json()["detail"] == "Send the upload as multipart/form-data."
    no_files = client.post("/api/v1/frames", files={"other": ("a", b"x")}, headers=auth(token))
    assert no_files.status_code == 400 and "`files`" in no_files.json()["detail"]
    assert client.get("/api/v1/frames/4242", headers=auth(token)).status_code == 404
    assert client.get("/api/v1/frames/4242/image", headers=auth(token)).status_code == 404


def test_failed_commit_leaves_no_file_and_no_row(
    settings: Settings, session_factory, monkeypatch: pytest.MonkeyPatch
) -> None:
    storage = LocalStorage(settings.home)
    files = [ingest.IncomingFile(f"{i}.png", image_bytes(seed=40 + i)) for i in range(3)]
    with session_factory() as session:
        monkeypatch.setattr(
            session,
            "commit",
            lambda: (_ for _ in ()).throw(
                sa.exc.OperationalError("COMMIT", {}, Exception("disk I/O error"))
            ),
        )
        with pytest.raises(sa.exc.OperationalError):
            ingest.ingest_frames(
                session, storage, files, sequence_id=None, user=None, max_pixels=10**6
            )
    with session_factory() as session:
        assert session.scalar(sa.select(sa.func.count()).select_from(Frame)) == 0
    assert _stored_files(settings) == [] and _staged_files(settings) == []


def test_a_stored_file_deleted_while_a_request_arrives_is_written_again(
    settings: Settings, session_factory
) -> None:
    """A file already in the store is not staged when its copy arrives; if the last frame using
    it is deleted before the request is recorded, the upload writes it again."""
    storage = LocalStorage(settings.home)
    content = image_bytes(seed=95)
    with session_factory() as session:
        first = ingest.ingest_frames(
            session,
            storage,
            [ingest.IncomingFile("a.png", content)],
            sequence_id=None,
            user=None,
            max_pixels=10**6,
        ).stored[0]
        run = sequences.create_sequence(session, {"name": "later"}, None)
        checks = ingest.FrameChecks(storage, max_pixels=10**6)
        checks.add(ingest.IncomingFile("b.png", content))
        (checked,) = checks.results()  # checked while the file was there: nothing staged
        assert isinstance(checked, ingest.CheckedFrame) and checked.staged is not None
        assert checked.staged.temporary is None
        age_stored_files(settings.home, storage.grace_s + 1)  # its claim has lapsed
        deletion.delete_frames(session, storage, [first.id], force=True)
        assert _stored_files(settings) == []
        result = ingest.record_checked(session, storage, checks, sequence_id=run.id, user=None)
        assert storage.absolute(result.stored[0].path).read_bytes() == content
    assert _staged_files(settings) == []


def test_one_request_is_flushed_to_disk_in_one_batch_before_its_commit(
    settings: Settings, session_factory, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Every file is fsynced before any is renamed into place, then each directory that gained
    a name, then the rows are committed: nothing committed can name a file the disk lost."""
    storage = LocalStorage(settings.home)
    events: list[str] = []
    real_fsync, real_link = storage_module._fsync, storage_module.os.link
    monkeypatch.setattr(
        storage_module, "_fsync", lambda p: (events.append(f"fsync {p}"), real_fsync(p))[1]
    )
    monkeypatch.setattr(
        storage_module.os, "link", lambda a, b: (events.append("rename"), real_link(a, b))[1]
    )
    files = [ingest.IncomingFile(f"{i}.png", image_bytes(seed=60 + i)) for i in range(4)]
    with session_factory() as session:
        real_commit = session.commit
        monkeypatch.setattr(session, "commit", lambda: (events.append("commit"), real_commit())[1])
        result = ingest.ingest_frames(
            session, storage, files, sequence_id=None, user=None, max_pixels=10**6
        )
    assert len(result.stored) == 4 and len(_stored_files(settings)) == 4
    renames = [i for i, e in enumerate(events) if e == "rename"]
    files_synced = [i for i, e in enumerate(events) if e.startswith("fsync") and ".part" in e]
    dirs_synced = [i for i, e in enumerate(events) if e.startswith("fsync") and ".part" not in e]
    assert len(files_synced) == 4 and len(renames) == 4
    assert max(files_synced) < min(renames) and max(renames) < min(dirs_synced)
    assert max(dirs_synced) < events.index("commit")
    synced = {
        e.removeprefix("fsync ") for e in events if e.startswith("fsync") and ".part" not in e
    }
    parents = {str(storage.absolute(row.path).parent) for row in result.stored}
    assert parents <= synced  # every directory that received a file


def test_a_failed_flush_leaves_no_file(
    settings: Settings, session_factory, monkeypatch: pytest.MonkeyPatch
) -> None:
    storage = LocalStorage(settings.home)

    def broken(path: Path) -> None:
        raise OSError(5, "Input/output error")

    monkeypatch.setattr(storage_module, "_fsync", broken)
    files = [ingest.IncomingFile(f"{i}.png", image_bytes(seed=70 + i)) for i in range(3)]
    with session_factory() as session, pytest.raises(OSError):
        ingest.ingest_frames(session, storage, files, sequence_id=None, user=None, max_pixels=10**6)
    with session_factory() as session:
        assert session.scalar(sa.select(sa.func.count()).select_from(Frame)) == 0
    assert _stored_files(settings) == [] and list((settings.home / "tmp").glob("*")) == []


def test_files_left_by_a_crash_are_swept(settings: Settings, session_factory) -> None:
    storage = LocalStorage(settings.home)
    with session_factory() as session:
        kept = ingest.ingest_frames(
            session,
            storage,
            [ingest.IncomingFile("k.png", image_bytes(seed=50))],
            sequence_id=None,
            user=None,
            max_pixels=10**6,
        ).stored[0]
        orphan = storage.put(image_bytes(seed=51), "f" * 64, ".png")  # renamed, never committed
        assert sweep_orphan_files(session, storage, older_than_s=3600) == 0  # too new
        assert sweep_orphan_files(session, storage, older_than_s=0) == 1
        again = storage.put(image_bytes(seed=52), "e" * 64, ".png")
    collector = FileCollector(session_factory, storage)  # the web process's thread
    collector._next_full = 0.0  # its daily listing of the store is due
    assert collector.sweep() == 0  # claimed within the grace period
    collector._next_full = 0.0
    age_stored_files(settings.home, storage.grace_s + 1)
    assert collector.sweep() == 1
    assert not storage.absolute(orphan.path).exists() and not storage.absolute(again.path).exists()
    assert storage.absolute(kept.path).exists()


def test_listing_filters_pagination_and_queue_order(
    client: TestClient, token: str, session_factory
) -> None:
    run = _sequence(client, token)
    files = [(f"{i}.png", image_bytes(seed=60 + i)) for i in range(5)]
    ids = [f["id"] for f in _upload(client, token, files, sequence_id=str(run)).json()["stored"]]
    _upload(client, token, [("loose.png", image_bytes(seed=70))])
    with session_factory() as session:
        for frame_id, score in zip(ids, [0.1, None, 0.9, 0.5, None], strict=True):
            session.get_one(Frame, frame_id).uncertainty = score
        session.commit()
    page = client.get(
        "/api/v1/frames", params={"sequence_id": run, "limit": 2, "offset": 2}, headers=auth(token)
    ).json()
    assert page["total"] == 5 and [f["id"] for f in page["items"]] == ids[2:4]
    queue = client.get(
        "/api/v1/frames", params={"sequence_id": run, "order": "uncertainty"}, headers=auth(token)
    ).json()["items"]
    assert [f["id"] for f in queue] == [ids[2], ids[3], ids[0], ids[1], ids[4]]
    by_status = client.get(
        "/api/v1/frames", params={"status": "new", "split": "train"}, headers=auth(token)
    ).json()
    assert by_status["total"] == 6
    assert (
        client.get("/api/v1/frames", params={"status": "bogus"}, headers=auth(token)).status_code
        == 422
    )
    detail = client.get(f"/api/v1/frames/{ids[0]}", headers=auth(token)).json()
    assert detail == detail | {
        "label": None,
        "proposal": None,
        "has_validation_keypoints": False,
        "status": "new",
        "split": "train",
    }
    listed = client.get("/api/v1/sequences", headers=auth(token)).json()
    assert listed[0]["frame_count"] == 5


@pytest.mark.parametrize("order", ["id", "-id", "frame_index", "uncertainty"])
def test_walking_a_list_by_cursor_gives_the_offset_order_exactly(
    client: TestClient, token: str, session_factory, order: str
) -> None:
    """Keyset pages (``after`` = the previous page's ``next_after``) list every frame once, in
    the order the offsets give: with NULL sequences, NULL frame indices, tied and missing
    scores, on both databases (which sort NULLs at opposite ends), and through the queue's
    diversity head."""
    runs = [_sequence(client, token, f"run {i}") for i in range(2)]
    rows = []
    for i in range(23):
        rows.append(
            Frame(
                sequence_id=None if i % 7 == 0 else runs[i % 2],
                sha256=f"{i:064x}",
                path=f"frames/x/{i}.png",
                original_name=f"{i}.png",
                media_type="image/png",
                size_bytes=1,
                width=4,
                height=4,
                channels=1,
                frame_index=None if i % 5 == 0 else (i * 7) % 4,  # ties and NULLs
                uncertainty=None if i % 6 == 0 else [0.25, 0.5, 0.75][i % 3],  # ties and NULLs
            )
        )
    with session_factory() as session:
        session.add_all(rows)
        session.commit()
    headers = auth(token)
    for scope, count in (({}, 23), ({"sequence_id": runs[0]}, 10)):
        whole = client.get(
            "/api/v1/frames", params={"order": order, "limit": 500, **scope}, headers=headers
        ).json()
        expected = [f["id"] for f in whole["items"]]
        assert len(expected) == count
        walked, after, pages = [], None, 0
        while True:
            params: dict[str, Any] = {"order": order, "limit": 4, **scope}
            if after:
                params["after"] = after
            page = client.get("/api/v1/frames", params=params, headers=headers).json()
            walked += [f["id"] for f in page["items"]]
            after, pages = page["next_after"], pages + 1
            if after is None:
                break
        assert walked == expected and pages == count // 4 + 1, scope
        assert page["total"] == count
    nothing = {"order": order, "status": "rejected"}  # an empty list (the queue: an empty head)
    empty = client.get("/api/v1/frames", params=nothing, headers=headers)
    assert (
        empty.status_code == 200 and empty.json()["items"] == [] and not empty.json()["next_after"]
    )
    if order == "uncertainty":  # through a head of 5 reordered for diversity, pages of 4
        with session_factory() as session:
            walk = {"order": order, "limit": 4, "diversity": 1.0, "diversity_pool": 5}
            by_offset = [
                f.id
                for offset in range(0, 24, 4)
                for f in listing.list_frames(session, offset=offset, **walk).rows
            ]
            by_cursor, cursor = [], None
            while True:
                result = listing.list_frames(session, after=cursor, **walk)
                by_cursor += [f.id for f in result.rows]
                if (cursor := result.next_after) is None:
                    break
        assert by_cursor == by_offset and sorted(by_cursor) == sorted(r.id for r in rows)


def test_a_foreign_cursor_or_a_cursor_with_an_offset_is_a_clear_400(
    client: TestClient, token: str
) -> None:
    headers = auth(token)
    for params in (
        {"order": "id", "after": "uncertainty~0.5~3"},
        {"order": "uncertainty", "after": "uncertainty~x~3"},
        {"order": "frame_index", "after": "frame_index~1~2"},
        {"order": "id", "after": "id~null"},
        {"order": "id", "after": "id~3", "offset": 5},
        # Beyond the database's integers, NULL where the key has none, a position before the head
        {"order": "id", "after": "id~99999999999999999999999"},
        {"order": "-id", "after": "-id~-99999999999999999999999"},
        {"order": "frame_index", "after": "frame_index~1~99999999999999999999~2"},
        {"order": "uncertainty", "after": "uncertainty~0.5~99999999999999999999999"},
        {"order": "uncertainty", "after": "uncertainty~nan~3"},
        {"order": "uncertainty", "after": "uncertainty~null~3"},
        {"order": "uncertainty", "after": "uncertainty~head~99999999999999999999999"},
        {"order": "uncertainty", "after": "uncertainty~head~-1"},
    ):
        answer = client.get("/api/v1/frames", params=params, headers=headers)
        assert answer.status_code == 400, params
        assert "`after`" in answer.json()["detail"]


def test_the_unreviewed_filter_is_new_and_proposed_frames(
    client: TestClient, token: str, session_factory
) -> None:
    from app.core.models import Frame, FrameStatus

    stored = _upload(client, token, [(f"u{i}.png", image_bytes(seed=60 + i)) for i in range(5)])
    ids = [f["id"] for f in stored.json()["stored"]]
    statuses = [FrameStatus.new, FrameStatus.proposed, FrameStatus.accepted, FrameStatus.corrected]
    with session_factory() as session:
        for frame_id, status in zip(ids, [*statuses, FrameStatus.rejected], strict=True):
            session.get_one(Frame, frame_id).status = status
        session.commit()

    def listed(status: str) -> list[int]:
        page = client.get("/api/v1/frames", params={"status": status}, headers=auth(token))
        assert page.status_code == 200, page.text
        return [f["id"] for f in page.json()["items"]]

    assert listed("unreviewed") == ids[:2]
    assert listed("all") == ids
    assert listed("accepted") == [ids[2]]
    bad = client.get("/api/v1/frames", params={"status": "done"}, headers=auth(token))
    assert bad.status_code == 422


def test_start_up_prunes_training_state_of_recorded_versions(
    settings: Settings, session_factory
) -> None:
    """Versions made before the training job pruned its state lose it at the next start-up;
    the weights stay, and folders without a version (a run to resume) are left alone."""
    from app.core.housekeeping import prune_training_state
    from app.core.models import ModelVersion

    recorded, unrecorded = settings.home / "models" / "student-v1", settings.home / "work" / "run"
    for folder in (recorded, unrecorded):
        folder.mkdir(parents=True)
        (folder / "model.safetensors").write_bytes(b"w" * 10)
        (folder / "training_state.pt").write_bytes(b"s" * 1000)
    with session_factory() as session:
        session.add(ModelVersion(name="student-v1", checkpoint_path="models/student-v1"))
        session.add(ModelVersion(name="student-v0", checkpoint_path=None))
        session.commit()
        assert prune_training_state(session, LocalStorage(settings.home)) == 1000
        assert prune_training_state(session, LocalStorage(settings.home)) == 0
    assert (recorded / "model.safetensors").exists()
    assert not (recorded / "training_state.pt").exists()
    assert (unrecorded / "training_state.pt").exists()


@pytest.mark.parametrize(
    ("order", "status", "index"),
    [
        # by id, PostgreSQL may as well walk the primary key and skip the other runs' rows
        ("id", None, ("ix_frames_sequence_id", "pk_frames")),
        ("frame_index", None, ("ix_frames_sequence_index",)),
        ("uncertainty", "unreviewed", ("ix_frames_queue_sequence",)),
        ("uncertainty", None, ("ix_frames_sequence_uncertainty",)),
    ],
)
def test_each_list_order_of_a_run_reads_its_index_instead_of_sorting(
    session_factory, order: str, status: str | None, index: tuple[str, ...]
) -> None:
    """With a run's worth of frames, the planner walks the list's index in order (no sort of
    the run) on SQLite and PostgreSQL: a page stays as quick at frame 50,000 as at frame 50."""
    from app.core.models import Frame, FrameStatus, Sequence
    from app.frames.listing import list_query

    with session_factory() as session:
        runs = [Sequence(name=f"run {i}") for i in range(3)]
        session.add_all(runs)
        session.flush()
        run = runs[1]
        rows = [
            {
                "sequence_id": runs[i % 3].id,
                "sha256": f"{i:064x}",
                "path": f"f/{i}.png",
                "media_type": "image/png",
                "size_bytes": 1,
                "width": 8,
                "height": 8,
                "frame_index": i,
                "status": FrameStatus.proposed if i % 5 else FrameStatus.accepted,
                "uncertainty": (i * 37 % 100) / 100 if i % 7 else None,
            }
            for i in range(4500)
        ]
        session.execute(sa.insert(Frame), rows)
        session.commit()
        dialect = session.get_bind().dialect.name
        if dialect == "postgresql":
            session.execute(sa.text("ANALYZE frames"))
        query, _ = list_query(sequence_id=run.id, status=status, order=order)
        # The first page (PostgreSQL weighs the cost of a deep offset and may then sort instead)
        compiled = query.limit(50).compile(
            session.get_bind(), compile_kwargs={"literal_binds": True}
        )
        explain = "EXPLAIN QUERY PLAN " if dialect == "sqlite" else "EXPLAIN "
        plan = "\n".join(
            " ".join(map(str, row)) for row in session.execute(sa.text(explain + str(compiled)))
        )
    assert any(name in plan for name in index), plan
    assert "TEMP B-TREE" not in plan and "Sort" not in plan, plan


def test_the_first_sweep_runs_after_start_not_before_serve_answers(
    settings: Settings, session_factory, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`serve` answers before any sweep: the collector's first pass (doomed files and training
    state) runs in its thread a little after start, then every third of the grace period; it
    looks at the files whose rows went, never listing the whole store (that is daily)."""
    import app.core.housekeeping as housekeeping

    storage = LocalStorage(settings.home)
    orphan = storage.put(image_bytes(seed=53), "d" * 64, ".png")
    with session_factory() as session:  # a transaction deleted the row naming it
        housekeeping.doom(session, {orphan.path})
        session.commit()
    age_stored_files(settings.home, storage.grace_s + 1)

    def listing(*_args: object, **_kwargs: object) -> None:
        raise AssertionError("the collector listed the whole store")

    monkeypatch.setattr(storage, "sweep_orphans", listing)
    monkeypatch.setattr(housekeeping, "FIRST_SWEEP_AFTER_S", 0.05)
    collector = FileCollector(session_factory, storage)
    assert collector.interval_s == storage.grace_s / 3 and collector.first_after_s == 0.05
    collector.start()
    try:
        wait_for(lambda: not storage.absolute(orphan.path).exists(), timeout=10)
    finally:
        collector.stop()
    with session_factory() as session:  # collected, and forgotten
        assert session.scalar(sa.select(sa.func.count()).select_from(DoomedFile)) == 0


def test_a_deleted_frames_file_claimed_meanwhile_stays_doomed_until_its_grace_ends(
    settings: Settings, session_factory
) -> None:
    """A deletion collects its frames' files at once unless an upload claimed one meanwhile:
    that one stays recorded and a later pass collects it once its grace has passed; a file a
    row names again is forgotten, never removed."""
    from app.core.housekeeping import collect_doomed
    from app.frames.deletion import delete_frames

    storage = LocalStorage(settings.home)
    with session_factory() as session:
        stored = ingest.ingest_frames(
            session,
            storage,
            [ingest.IncomingFile(f"d{i}.png", image_bytes(seed=90 + i)) for i in range(2)],
            sequence_id=None,
            user=None,
            max_pixels=10**6,
        ).stored
        age_stored_files(settings.home, storage.grace_s + 1)
        again = storage.put(b"", stored[1].sha256, Path(stored[1].path).suffix)  # an upload
        assert not again.created  # of the same content: it claims the stored file
        assert delete_frames(session, storage, [f.id for f in stored], force=False).files == 1
        doomed = set(session.scalars(sa.select(DoomedFile.path)))
        assert doomed == {stored[1].path}
        assert collect_doomed(session, storage) == []  # claimed within the grace period
        age_stored_files(settings.home, storage.grace_s + 1)
        assert collect_doomed(session, storage) == [stored[1].path]
        assert not storage.absolute(stored[1].path).exists()
        assert session.scalar(sa.select(sa.func.count()).select_from(DoomedFile)) == 0
