"""A file written straight into a store's scratch folder as it arrives (an upload's spool), hashed
on the way when asked, so that ``Storage.put_file`` can rename it into its content path: the
bytes are written once, never copied."""

from __future__ import annotations

import hashlib
import io
import uuid
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO

if TYPE_CHECKING:
    from app.storage.protocol import Storage, StoredFile


class ScratchSpool(io.FileIO):
    """A new file in ``folder`` (``upload-<uuid>.part``: swept a day later if left behind),
    readable and seekable, that counts the bytes written through it and (``hashed``) hashes
    them in order: the form writes its part once, start to end, before anyone reads it."""

    def __init__(self, folder: Path, *, hashed: bool = False) -> None:
        super().__init__(str(folder / f"upload-{uuid.uuid4().hex}.part"), "x+b")
        self._digest = hashlib.sha256() if hashed else None
        self.size = 0
        """Bytes written so far."""

    @property
    def path(self) -> Path:
        """Where the spool is (until it is moved)."""
        return Path(str(self.name))

    @property
    def sha256(self) -> str | None:
        """The hash of the bytes written so far; None when the spool is not ``hashed``."""
        return None if self._digest is None else self._digest.hexdigest()

    def write(self, data: bytes | bytearray | memoryview) -> int:  # type: ignore[override]
        """Write all of ``data`` (a raw file may take part of it per call) and hash it."""
        view = memoryview(data).cast("B")
        total = view.nbytes
        if self._digest is not None:
            self._digest.update(view)
        while view:
            view = view[super().write(view) :]
        self.size += total
        return total


def put_upload(
    storage: Storage, source: BinaryIO, extension: str, area: str
) -> tuple[StoredFile, str, int]:
    """Store an uploaded file under its content name; returns (file, sha256, size). A hashed
    ``ScratchSpool`` of the store's scratch folder is renamed into place (``put_file``: written
    once); any other stream (a file on the command line, a part held in memory) is copied
    (``put_stream``)."""
    if isinstance(source, ScratchSpool) and source.path.parent == storage.scratch():
        sha256 = source.sha256
        if sha256 is not None:
            return storage.put_file(source.path, sha256, extension, area), sha256, source.size
    return storage.put_stream(source, extension, area)
