"""`weldpool import s3://…` and `weldpool import-labels s3://…`: a bucket a camera rig (or
another tool) fills feeds a run, into an instance on home or on its own object store."""

from __future__ import annotations

from pathlib import Path

import boto3
import cv2
import numpy as np
import sqlalchemy as sa

from app.core.db import create_db_engine, create_session_factory
from app.core.models import Frame, Label, LabelStatus, Role, Sequence, User
from tests.helpers import run_cli
from tests.s3 import bucket_keys, make_bucket
from weldpool_core.synth import SynthParams, synth_sequence

SIZE = SynthParams(width=96, height=64)


def _rows(home: Path) -> tuple[dict[str, int], list[Label]]:
    engine = create_db_engine(f"sqlite:///{home / 'weldpool.sqlite3'}")
    with create_session_factory(engine)() as session:
        runs = {
            s.name: session.scalar(
                sa.select(sa.func.count(Frame.id)).where(Frame.sequence_id == s.id)
            )
            or 0
            for s in session.scalars(sa.select(Sequence))
        }
        labels = list(session.scalars(sa.select(Label)))
    engine.dispose()
    return runs, labels


def test_frames_and_labels_come_in_from_a_bucket(
    tmp_path: Path, s3_endpoint: str, s3_url: str
) -> None:
    rig = make_bucket(s3_endpoint)
    client = boto3.client("s3", endpoint_url=s3_endpoint)
    frames = synth_sequence(seed=3, length=5, params=SIZE)
    for index, frame in enumerate(frames[:3]):
        body = cv2.imencode(".png", frame.image)[1].tobytes()
        client.put_object(Bucket=rig, Key=f"cell-4/day1/f{index}.png", Body=body)
    client.put_object(Bucket=rig, Key="cell-4/day1/notes.txt", Body=b"not a frame")
    for index, frame in enumerate(frames[3:]):  # a mask folder, as another tool writes it
        image = cv2.imencode(".png", frame.image)[1].tobytes()
        mask = cv2.imencode(".png", frame.mask.astype(np.uint8) * 255)[1].tobytes()
        client.put_object(Bucket=rig, Key=f"exports/set/images/m{index}.png", Body=image)
        client.put_object(Bucket=rig, Key=f"exports/set/masks/m{index}.png", Body=mask)

    home = tmp_path / "home"
    env = {
        "WELDPOOL_HOME": str(home),
        "WELDPOOL_S3_ENDPOINT_URL": s3_endpoint,
        "WELDPOOL_STORAGE_URL": s3_url,  # the instance keeps its files in its own bucket
    }
    assert run_cli("migrate", env=env).returncode == 0
    engine = create_db_engine(f"sqlite:///{home / 'weldpool.sqlite3'}")
    with create_session_factory(engine)() as session:
        session.add(User(username="lead", password_hash="x", role=Role.admin))
        session.commit()
    engine.dispose()
    done = run_cli("import", f"s3://{rig}/cell-4/day1", "--sequence", "day 1", env=env)
    assert done.returncode == 0, done.stderr
    assert "3 frames stored" in done.stderr
    again = run_cli("import", f"s3://{rig}/cell-4/day1", "--sequence", "day 1", env=env)
    assert "0 frames stored, 3 duplicates" in again.stderr  # the rig's next drop adds only news

    labels = run_cli("import-labels", f"s3://{rig}/exports/set", "--format", "masks", env=env)
    assert labels.returncode == 0, labels.stderr
    runs, rows = _rows(home)
    assert runs["day 1"] == 3 and sum(runs.values()) == 5
    assert len(rows) == 2 and {r.status for r in rows} == {LabelStatus.corrected}
    stored = bucket_keys(s3_endpoint, s3_url)
    assert sum(k.startswith("frames/") for k in stored) == 5  # in the instance's bucket
    assert sum(k.startswith("artefacts/") for k in stored) == 2  # the two masks
    assert not list((home / "tmp").glob("weldpool-bucket-*"))  # the copies are gone

    missing = run_cli("import", f"s3://{rig}/no/such/prefix", "--sequence", "x", env=env)
    assert missing.returncode == 2
    assert missing.stderr.strip().splitlines()[-1].startswith("weldpool: s3://")
    assert "does not exist" in missing.stderr and "Traceback" not in missing.stderr
    bad = run_cli("import-labels", "s3://", "--format", "masks", env=env)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr
