"""Where an uploaded import waits for its job: under ``imports/`` of the home, published to
every machine, removed when the job ends (a day at most)."""

from __future__ import annotations

import os
import shutil
import uuid
from pathlib import Path
from typing import BinaryIO

from app.storage import CHUNK, Storage

IMPORTS_DIR = "imports"
"""Where an uploaded import waits for its job (removed when the job ends; a day at most)."""


def upload_name(name: str) -> str:
    """Where the file an import job reads is stored (``name`` is the job's, never a
    client's)."""
    return f"{IMPORTS_DIR}/{Path(name).name}"


def keep_upload(storage: Storage, source: BinaryIO, suffix: str) -> str:
    """Copy an uploaded file (a spooled part) under ``imports/``, flushed and published to
    every machine (a worker elsewhere reads it); its name."""
    folder = storage.local(IMPORTS_DIR)
    folder.mkdir(parents=True, exist_ok=True)
    name = f"{uuid.uuid4().hex}{suffix}"
    target = folder / name
    try:
        with open(target, "wb") as handle:
            shutil.copyfileobj(source, handle, CHUNK)
            handle.flush()
            os.fsync(handle.fileno())
        storage.publish(upload_name(name))
    except BaseException:
        target.unlink(missing_ok=True)
        raise
    return name
