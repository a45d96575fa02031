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
    """Put an uploaded file (a spooled part) under ``imports/``, flushed and published to every
    machine (a worker elsewhere reads it); its name. A part spooled to a named file in the
    store's scratch folder (``one_spooled_file``'s ``spool_dir``) is moved there, not copied."""
    folder = storage.local(IMPORTS_DIR)
    folder.mkdir(parents=True, exist_ok=True)
    name = f"{uuid.uuid4().hex}{suffix}"
    target = folder / name
    try:
        if not _moved(storage, source, target):
            with open(target, "wb") as handle:
                shutil.copyfileobj(source, handle, CHUNK)
                handle.flush()
                os.fsync(handle.fileno())
        storage.publish(upload_name(name))
    except BaseException:
        target.unlink(missing_ok=True)
        raise
    return name


def _moved(storage: Storage, source: BinaryIO, target: Path) -> bool:
    """Flush a part spooled to a named file in the store's scratch folder and rename it to
    ``target`` (written once); False for any other source (a file elsewhere, in memory)."""
    spooled = Path(str(getattr(source, "name", "")))
    if spooled.parent != storage.scratch() or not spooled.is_file():
        return False
    source.flush()
    os.fsync(source.fileno())
    try:
        os.rename(spooled, target)
    except OSError:  # another filesystem after all: copied instead
        source.seek(0)
        return False
    return True
