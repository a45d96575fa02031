"""The object-store backend against a real S3-protocol server (moto's, on 127.0.0.1): the
storage seam's promises (content-addressed, written before its row, claims, one collector
through the trash, a bounded cache, streamed files) hold as they do in home."""

from __future__ import annotations

import hashlib
import io
import os
import time
from pathlib import Path

import boto3
import pytest

from app.core.config import StoreWaits
from app.storage import LocalStorage, open_storage
from app.storage.s3 import TRASH, ObjectStorage
from tests.s3 import bucket_keys


def store(tmp_path: Path, name: str, url: str, endpoint: str, **kwargs: object) -> ObjectStorage:
    kwargs.setdefault("waits", StoreWaits(connect_s=3.0, read_s=60.0, attempts=5))
    return ObjectStorage(tmp_path / name, url, 60.0, endpoint, **kwargs)  # type: ignore[arg-type]


def content(seed: int, size: int = 10_000) -> tuple[bytes, str]:
    data = hashlib.sha256(str(seed).encode()).digest() * (size // 32)
    return data, hashlib.sha256(data).hexdigest()


def age(endpoint: str, url: str, relative: str, seconds: float) -> None:
    """Make an object look claimed ``seconds`` ago (time passing, for the collector)."""
    from app.storage.s3 import parse_url

    bucket, prefix = parse_url(url)
    then = str(time.time_ns() - int(seconds * 1e9))
    key = f"{prefix}/{relative}"
    boto3.client("s3", endpoint_url=endpoint).copy_object(
        Bucket=bucket,
        Key=key,
        CopySource={"Bucket": bucket, "Key": key},
        MetadataDirective="REPLACE",
        Metadata={"claimed": then},
    )


def test_a_file_written_on_one_machine_is_read_on_another(
    tmp_path: Path, s3_url: str, s3_endpoint: str
) -> None:
    web, worker = (
        store(tmp_path, "web", s3_url, s3_endpoint),
        store(tmp_path, "worker", s3_url, s3_endpoint),
    )
    data, sha = content(1)
    stored = web.put(data, sha, ".png")
    assert stored.created and bucket_keys(s3_endpoint, s3_url) == {stored.path: len(data)}
    assert (web.home / stored.path).read_bytes() == data  # written through the cache

    assert worker.reads == 0
    assert worker.absolute(stored.path).read_bytes() == data  # fetched once …
    assert worker.absolute(stored.path).read_bytes() == data  # … then read from the cache
    assert worker.reads == 1
    assert not worker.put(data, sha, ".png").created  # the same content: claimed, not written
    missing = worker.absolute("frames/00/00/none.png")
    assert not missing.exists()  # a key nobody stored: no file, as in home


def test_staged_files_are_in_the_bucket_before_install_and_withdrawn_by_unstage(
    tmp_path: Path, s3_url: str, s3_endpoint: str
) -> None:
    web = store(tmp_path, "web", s3_url, s3_endpoint)
    (a, sha_a), (b, sha_b) = content(2), content(3)
    staged = [web.stage(a, sha_a, ".png"), web.stage(b, sha_b, ".png")]
    assert set(bucket_keys(s3_endpoint, s3_url)) == {s.relative for s in staged}
    installed = web.install_many(staged[:1])
    assert installed[0].created and (web.home / installed[0].path).read_bytes() == a
    web.unstage(staged[1:])  # a duplicate, not installed: its upload goes (to the trash)
    assert set(bucket_keys(s3_endpoint, s3_url, "frames/")) == {installed[0].path}
    assert not list(web.scratch().glob("*.part"))


def test_discard_spares_content_another_writer_claimed_since(
    tmp_path: Path, s3_url: str, s3_endpoint: str
) -> None:
    first, second = (
        store(tmp_path, "a", s3_url, s3_endpoint),
        store(tmp_path, "b", s3_url, s3_endpoint),
    )
    data, sha = content(4)
    written = first.put(data, sha, ".png")
    assert not second.put(data, sha, ".png").created  # claimed by another writer
    assert first.discard([written]) == 0  # its commit failed, but the other one's row names it
    assert written.path in bucket_keys(s3_endpoint, s3_url)
    other, sha_o = content(5)
    lone = first.put(other, sha_o, ".png")
    assert first.discard([lone]) == 1 and lone.path not in bucket_keys(s3_endpoint, s3_url)
    assert not (first.home / lone.path).exists()  # the cached copy went with it


def test_the_collector_takes_only_unnamed_files_past_their_grace(
    tmp_path: Path, s3_url: str, s3_endpoint: str
) -> None:
    web = store(tmp_path, "web", s3_url, s3_endpoint)
    old, named, fresh = (web.put(*content(10 + i), ".png") for i in range(3))
    age(s3_endpoint, s3_url, old.path, 120)
    age(s3_endpoint, s3_url, named.path, 120)
    removed = web.collect([old.path, named.path, fresh.path], in_use={named.path})
    assert removed == [old.path]
    keys = bucket_keys(s3_endpoint, s3_url)
    assert old.path not in keys and f"{TRASH}/{old.path}" in keys
    assert {named.path, fresh.path} <= set(keys)

    # The sweep: unnamed and old → trashed; fresh ones wait; the trash is purged after a grace.
    orphan = web.put(*content(20), ".png")
    age(s3_endpoint, s3_url, orphan.path, 120)
    swept = web.sweep_orphans(["frames"], known={named.path, fresh.path})
    assert swept == [orphan.path]
    assert {f"{TRASH}/{orphan.path}", f"{TRASH}/{old.path}"} <= set(
        bucket_keys(s3_endpoint, s3_url, f"{TRASH}/")
    )
    web.grace_s = 0.0  # a grace period later
    time.sleep(1.1)  # LastModified counts whole seconds
    web.sweep_orphans(["frames"], known={named.path, fresh.path})
    assert bucket_keys(s3_endpoint, s3_url, f"{TRASH}/") == {}
    assert set(bucket_keys(s3_endpoint, s3_url, "frames/")) == {named.path, fresh.path}


def test_a_claim_that_lands_while_the_collector_removes_is_not_lost(
    tmp_path: Path, s3_url: str, s3_endpoint: str
) -> None:
    """S3 has no rename: the collector's look and its delete are two requests, and a writer's
    claim can fall between them. Its row then names a trashed object: a reader puts it back,
    and so does the sweep, before the trash is ever purged."""
    web, worker = (
        store(tmp_path, "web", s3_url, s3_endpoint),
        store(tmp_path, "worker", s3_url, s3_endpoint),
    )
    data, sha = content(30)
    stored = web.put(data, sha, ".png")
    age(s3_endpoint, s3_url, stored.path, 120)
    looked = web.objects.claim_ns(stored.path)  # the collector looks: unclaimed for two minutes
    assert not worker.put(data, sha, ".png").created  # a writer claims it, then commits
    assert web.trash.remove_if(stored.path, lambda ns: looked is not None)  # the collector deletes
    assert stored.path not in bucket_keys(s3_endpoint, s3_url)

    reader = store(tmp_path, "reader", s3_url, s3_endpoint)
    assert reader.absolute(stored.path).read_bytes() == data  # fetched: put back from the trash
    assert stored.path in bucket_keys(s3_endpoint, s3_url)

    web.trash.remove_if(stored.path, lambda ns: True)  # the same race again, and no reader comes
    web.grace_s = 0.0
    time.sleep(1.1)
    web.sweep_orphans(["frames"], known={stored.path})  # the row names it: restored, not purged
    keys = bucket_keys(s3_endpoint, s3_url)
    assert stored.path in keys and f"{TRASH}/{stored.path}" not in keys


def test_the_cache_keeps_to_its_bound_least_recently_used_out(
    tmp_path: Path, s3_url: str, s3_endpoint: str
) -> None:
    from app.storage.s3 import IN_USE_S

    writer = store(tmp_path, "writer", s3_url, s3_endpoint)
    files = [writer.put(*content(40 + i, 20_000), ".png") for i in range(7)]
    reader = store(tmp_path, "reader", s3_url, s3_endpoint, cache_bytes=70_000)
    for index, stored in enumerate(files[:6]):  # read one after another, long ago
        path = reader.absolute(stored.path)
        then = time.time() - IN_USE_S - 1000 + index
        os.utime(path, (then, then))
    assert reader.absolute(files[6].path).is_file()  # this fetch passes the bound: a trim
    cached = [(reader.home / f.path).exists() for f in files]
    assert sum(cached) * 20_000 <= 0.8 * 70_000 + 20_000 and cached[-1]
    assert cached == [False] * (7 - sum(cached)) + [True] * sum(cached)  # the oldest went first
    assert not cached[0] and reader.absolute(files[0].path).read_bytes() == content(40, 20_000)[0]


def test_the_cache_never_evicts_a_file_just_handed_out(
    tmp_path: Path, s3_url: str, s3_endpoint: str
) -> None:
    writer = store(tmp_path, "writer", s3_url, s3_endpoint)
    big, small = writer.put(*content(50, 60_000), ".png"), writer.put(*content(51), ".png")
    reader = store(tmp_path, "reader", s3_url, s3_endpoint, cache_bytes=50_000)
    path = reader.absolute(big.path)  # larger than the whole bound
    assert path.is_file() and reader.absolute(small.path).is_file()
    assert reader.trim_cache() == 0 and path.is_file()  # in use: kept past the bound


def test_videos_stream_in_parts_and_folders_are_published_whole(
    tmp_path: Path, s3_url: str, s3_endpoint: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    import app.storage.s3.bucket as s3

    monkeypatch.setattr(s3, "MULTIPART_BYTES", 5 * 1024 * 1024)  # S3's smallest part
    web, worker = (
        store(tmp_path, "web", s3_url, s3_endpoint),
        store(tmp_path, "worker", s3_url, s3_endpoint),
    )
    video = os.urandom(12 * 1024 * 1024)
    stored, sha, size = web.put_stream(io.BytesIO(video), ".mp4", "videos")
    assert size == len(video) and sha == hashlib.sha256(video).hexdigest()
    head = web.objects.client.head_object(Bucket=web.objects.name, Key=web.objects.key(stored.path))
    assert "-" in head["ETag"]  # a multipart upload: sent in parts, never one body in memory
    assert hashlib.sha256(worker.absolute(stored.path).read_bytes()).hexdigest() == sha

    folder = web.home / "models" / "student-v1"
    (folder / "sub").mkdir(parents=True)
    (folder / "model.safetensors").write_bytes(b"w" * 100)
    (folder / "sub" / "cell.json").write_text("{}")
    assert worker.folder("models/student-v1") is None and not worker.has_folder("models/student-v1")
    web.publish("models/student-v1")
    assert worker.has_folder("models/student-v1")
    fetched = worker.folder("models/student-v1")
    assert fetched is not None and (fetched / "sub" / "cell.json").read_text() == "{}"
    (fetched / "student.onnx").write_bytes(b"made here from the weights")  # this machine's own
    time.sleep(1.1)  # LastModified counts whole seconds
    (folder / "sub" / "cell.json").write_text("[]")  # a job replaced a file (same size)
    (folder / "int8.onnx").write_bytes(b"q")
    web.publish("models/student-v1")
    fetched = worker.folder("models/student-v1")
    assert fetched is not None
    assert sorted(p.name for p in fetched.rglob("*") if p.is_file()) == [
        "cell.json",
        "int8.onnx",
        "model.safetensors",
        "student.onnx",
    ]
    assert (fetched / "sub" / "cell.json").read_text() == "[]"  # the newer one
    web.unpublish("models/student-v1")
    assert bucket_keys(s3_endpoint, s3_url, "models/") == {}


def test_settings_choose_the_backend_and_a_bad_store_is_one_sentence(
    tmp_path: Path, s3_url: str, s3_endpoint: str
) -> None:
    from pydantic import ValidationError

    from app.core.errors import ConfigurationError
    from tests.helpers import make_settings

    assert type(open_storage(make_settings(tmp_path / "a"))) is LocalStorage
    remote = open_storage(
        make_settings(tmp_path / "b", storage_url=s3_url, s3_endpoint_url=s3_endpoint)
    )
    assert isinstance(remote, ObjectStorage) and remote.remote == s3_url
    remote.check()
    with pytest.raises(ValidationError, match="s3://bucket/prefix"):
        make_settings(tmp_path / "c", storage_url="gs://bucket")
    absent = open_storage(
        make_settings(
            tmp_path / "d", storage_url="s3://no-such-bucket-wp", s3_endpoint_url=s3_endpoint
        )
    )
    with pytest.raises(ConfigurationError, match="cannot be used"):
        absent.check()


def test_serve_and_worker_refuse_a_store_they_cannot_use_in_one_line(
    tmp_path: Path, s3_endpoint: str
) -> None:
    from tests.helpers import run_cli

    env = {
        "WELDPOOL_HOME": str(tmp_path / "home"),
        "WELDPOOL_STORAGE_URL": "s3://no-such-bucket-weldpool/lab",
        "WELDPOOL_S3_ENDPOINT_URL": s3_endpoint,
    }
    for command in (("worker",), ("serve", "--port", "1")):
        done = run_cli(*command, env=env, timeout=60)
        assert done.returncode == 2, done.stderr
        last = done.stderr.strip().splitlines()[-1]
        assert last.startswith("weldpool: The object store s3://no-such-bucket-weldpool/lab")
        assert "Traceback" not in done.stderr
    bad = run_cli("worker", env={**env, "WELDPOOL_STORAGE_URL": "ftp://x"}, timeout=60)
    assert bad.returncode == 2 and "s3://bucket/prefix" in bad.stderr


def test_a_store_that_stops_answering_is_a_503_and_stores_nothing(
    tmp_path: Path, session_factory: object, settings: object
) -> None:
    import cv2
    import numpy as np
    import sqlalchemy as sa
    from fastapi.testclient import TestClient

    from app.core.models import Frame, Role, User
    from app.core.security import issue_token
    from app.main import create_app
    from tests.helpers import auth, make_settings
    from tests.web.server import free_port

    dead = f"http://127.0.0.1:{free_port()}"  # nothing listens there
    broken = make_settings(
        tmp_path / "web",
        database_url=settings.resolved_database_url,  # type: ignore[attr-defined]
        storage_url="s3://gone/lab",
        s3_endpoint_url=dead,
    )
    with session_factory() as session:  # type: ignore[operator]
        user = User(username="lead", password_hash="x", role=Role.admin)
        session.add(user)
        session.flush()
        _, token = issue_token(session, user, "t")
        session.commit()
    png = cv2.imencode(".png", np.full((32, 48), 90, np.uint8))[1].tobytes()
    with TestClient(create_app(broken)) as client:
        answer = client.post(
            "/api/v1/frames", files=[("files", ("a.png", png, "image/png"))], headers=auth(token)
        )
    assert answer.status_code == 503, answer.text
    assert answer.json()["detail"].startswith("The object store did not answer")
    with session_factory() as session:  # type: ignore[operator]
        assert session.scalar(sa.select(sa.func.count(Frame.id))) == 0


def test_two_jobs_publishing_one_model_folder_keep_each_others_files(
    tmp_path: Path, s3_url: str, s3_endpoint: str
) -> None:
    """An int8 job and a sequential job on two workers, each from its own copy of a version's
    folder: each publishes only the files it changed."""
    trainer, a, b = (store(tmp_path, n, s3_url, s3_endpoint) for n in ("t", "a", "b"))
    (trainer.home / "models" / "v1").mkdir(parents=True)
    (trainer.home / "models" / "v1" / "model.safetensors").write_bytes(b"weights")
    trainer.publish("models/v1")
    first, second = a.folder("models/v1"), b.folder("models/v1")
    assert first is not None and second is not None
    (first / "sequential.json").write_text("{}")  # worker a trains a cell
    a.publish("models/v1", ("sequential.json", "sequential.onnx"))
    (second / "int8.onnx").write_bytes(b"q")  # worker b, whose copy has no cell, makes int8
    b.publish("models/v1", ("int8.onnx", "student.onnx"))
    assert set(bucket_keys(s3_endpoint, s3_url, "models/")) == {
        "models/v1/model.safetensors",
        "models/v1/sequential.json",
        "models/v1/int8.onnx",
    }
    (first / "sequential.json").unlink()  # a's job failed after all: its cell withdrawn
    a.publish("models/v1", ("sequential.json", "sequential.onnx"))
    assert "models/v1/int8.onnx" in bucket_keys(s3_endpoint, s3_url, "models/")
    assert "models/v1/sequential.json" not in bucket_keys(s3_endpoint, s3_url, "models/")
    with pytest.raises(FileNotFoundError):
        a.publish("models/v2")  # nothing here to publish: never a withdrawal of the bucket's


def test_a_home_with_files_of_its_own_is_pushed_before_it_becomes_a_cache(
    tmp_path: Path, s3_url: str, s3_endpoint: str
) -> None:
    from app.core.errors import ConfigurationError
    from tests.helpers import make_settings, run_cli

    home = tmp_path / "home"
    local = LocalStorage(home)  # an instance that kept its files in home
    data, sha = content(60)
    kept = local.put(data, sha, ".png")
    (home / "models" / "v1").mkdir(parents=True)
    (home / "models" / "v1" / "model.safetensors").write_bytes(b"w")
    remote = open_storage(make_settings(home, storage_url=s3_url, s3_endpoint_url=s3_endpoint))
    with pytest.raises(ConfigurationError, match="weldpool storage push"):
        remote.check()  # its cache would evict files no other machine has seen
    env = {"WELDPOOL_HOME": str(home), "WELDPOOL_STORAGE_URL": s3_url}
    pushed = run_cli("storage", "push", env={**env, "WELDPOOL_S3_ENDPOINT_URL": s3_endpoint})
    assert pushed.returncode == 0, pushed.stderr
    assert "2 files uploaded" in pushed.stderr
    assert set(bucket_keys(s3_endpoint, s3_url)) >= {kept.path, "models/v1/model.safetensors"}
    remote.check()
    other = store(tmp_path, "other", s3_url, s3_endpoint)
    assert other.absolute(kept.path).read_bytes() == data
    dead = run_cli("storage", "push", env={**env, "WELDPOOL_S3_ENDPOINT_URL": "http://127.0.0.1:9"})
    assert dead.returncode == 2 and "Traceback" not in dead.stderr
    assert dead.stderr.strip().splitlines()[-1].startswith("weldpool: The object store")


def test_files_fetched_ahead_are_read_from_the_cache(
    tmp_path: Path, s3_url: str, s3_endpoint: str
) -> None:
    """``fetch_ahead`` brings files into a machine's cache in the background (an export's or
    a training set's next files): reading them then asks the store for nothing; a key nobody
    stored is left for the read to find missing."""
    from tests.helpers import wait_for

    web, worker = (
        store(tmp_path, "web", s3_url, s3_endpoint),
        store(tmp_path, "worker", s3_url, s3_endpoint),
    )
    paths = [web.put(*content(40 + i), ".png").path for i in range(5)]
    worker.fetch_ahead([*paths, "frames/00/00/none.png"])
    wait_for(lambda: worker.reads == 5, timeout=30)
    assert [worker.existing(p).read_bytes() for p in paths] == [
        web.absolute(p).read_bytes() for p in paths
    ]
    assert worker.reads == 5  # each fetched once, ahead
    assert not worker.absolute("frames/00/00/none.png").exists()
    LocalStorage(tmp_path / "home").fetch_ahead(paths)  # home's files: nothing to do


def test_a_frame_is_uploaded_while_it_is_checked_and_a_refused_one_withdrawn(
    tmp_path: Path, s3_url: str, s3_endpoint: str
) -> None:
    """Ingest uploads a file whose header names an image while its check runs; the upload of
    one the check refuses (a cut PNG) is withdrawn: the bucket's frames are the good ones."""
    from app.frames import ingest
    from tests.helpers import image_bytes

    web = store(tmp_path, "web", s3_url, s3_endpoint)
    checks = ingest.FrameChecks(web, max_pixels=10**6)
    good, cut = image_bytes(seed=21), image_bytes(seed=22)[:300]
    checks.add(ingest.IncomingFile("a.png", good))
    checks.add(ingest.IncomingFile("cut.png", cut))
    first, refused = checks.results()
    assert isinstance(first, ingest.CheckedFrame) and isinstance(refused, ingest.Rejection)
    assert first.staged is not None
    assert set(bucket_keys(s3_endpoint, s3_url, "frames/")) == {first.staged.relative}
    installed = web.install_many([first.staged])
    assert (web.home / installed[0].path).read_bytes() == good
    assert not list(web.scratch().glob("*.part"))
