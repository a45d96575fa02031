"""Files under WELDPOOL_HOME: content-addressed, written atomically.

The database holds metadata and relative paths; the files live here. A file is written to a
temporary name, flushed to disk, then renamed into place, and only then is its row committed.
For a whole request this is two steps: ``stage`` writes and flushes each new file (in the
ingest's disk threads, as soon as it is checked), ``install_many`` renames them all into place and
flushes the directories that received them, so the rows committed next never name a file the
disk could lose.
If the commit fails, the files this attempt created are removed again; if the process dies
between rename and commit, ``sweep_orphans`` (run by ``weldpool serve``) removes the leftovers.
"""

from __future__ import annotations

import hashlib
import os
import time
import uuid
from collections.abc import Collection, Iterable, Sequence
from concurrent.futures import Executor, wait
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

CHUNK = 1024 * 1024


@dataclass(frozen=True)
class StagedFile:
    """Content written and flushed under a temporary name, not yet in the store."""

    relative: str
    temporary: Path | None  # None: the store holds this content already


@dataclass(frozen=True)
class StoredFile:
    """A file in the store: its path relative to home, and whether this call created it."""

    path: str
    created: bool


class Storage:
    """Content-addressed files under one home directory."""

    def __init__(self, home: Path) -> None:
        self.home = home.resolve()
        self.tmp = self.home / "tmp"

    def absolute(self, relative: str) -> Path:
        """The file behind a stored relative path (never outside home)."""
        path = (self.home / relative).resolve()
        if not path.is_relative_to(self.home):
            raise ValueError(f"{relative!r} is outside the store")
        return path

    @staticmethod
    def relative_path(area: str, sha256: str, extension: str) -> str:
        return f"{area}/{sha256[:2]}/{sha256[2:4]}/{sha256}{extension}"

    def _temporary(self) -> Path:
        self.tmp.mkdir(parents=True, exist_ok=True)
        return self.tmp / f"{uuid.uuid4().hex}.part"

    def _install(self, temporary: Path, relative: str) -> StoredFile:
        final = self.home / relative
        if final.exists():
            temporary.unlink()
            return StoredFile(relative, created=False)
        final.parent.mkdir(parents=True, exist_ok=True)
        os.replace(temporary, final)
        return StoredFile(relative, created=True)

    def put(self, data: bytes, sha256: str, extension: str, area: str = "frames") -> StoredFile:
        """Store ``data`` (whose hash the caller computed) unless the same content is there."""
        relative = self.relative_path(area, sha256, extension)
        if (self.home / relative).exists():
            return StoredFile(relative, created=False)
        return self._install(self._write_temporary(data), relative)

    def stage(self, data: bytes, sha256: str, extension: str, area: str = "frames") -> StagedFile:
        """Write new content to a temporary name and flush it to disk; nothing is in the store
        until ``install_many``. Any thread may stage (fsync releases the GIL), so a request's
        files reach the disk while the rest of it is still being checked."""
        relative = self.relative_path(area, sha256, extension)
        if (self.home / relative).exists():
            return StagedFile(relative, None)
        temporary = self._temporary()
        try:
            temporary.write_bytes(data)
            _fsync(temporary)
        except BaseException:
            temporary.unlink(missing_ok=True)
            raise
        return StagedFile(relative, temporary)

    def unstage(self, staged: Iterable[StagedFile]) -> None:
        """Remove staged temporaries that will not be installed."""
        for item in staged:
            if item.temporary is not None:
                item.temporary.unlink(missing_ok=True)

    def install_many(
        self, staged: Sequence[StagedFile], executor: Executor | None = None
    ) -> list[StoredFile]:
        """Rename staged files into place, then flush each directory that gained an entry once
        (in ``executor``'s threads when given), so a crash after this returns cannot lose a
        file or its name. On failure nothing of it is left: installed files and temporaries
        are removed."""
        touched: set[Path] = set()
        installed: list[StoredFile] = []
        results: list[StoredFile] = []
        try:
            for item in staged:
                if item.temporary is None:
                    results.append(StoredFile(item.relative, created=False))
                    continue
                final = self.home / item.relative
                touched.update(_created_parents(final.parent, self.home))
                touched.add(final.parent)
                stored = self._install(item.temporary, item.relative)
                results.append(stored)
                installed.append(stored)
            list(executor.map(_fsync, touched) if executor else map(_fsync, touched))
        except BaseException:
            self.discard(installed)
            self.unstage(staged)
            raise
        return results

    def stage_many(
        self,
        items: Sequence[tuple[bytes, str, str]],
        area: str = "frames",
        executor: Executor | None = None,
    ) -> list[StagedFile]:
        """``stage`` for many ``(data, sha256, extension)``, in ``executor``'s threads when
        given; if any fails, the others' temporaries are removed and its error raised."""
        if executor is None:
            staged: list[StagedFile] = []
            try:
                for item in items:
                    staged.append(self.stage(*item, area))
            except BaseException:
                self.unstage(staged)
                raise
            return staged
        futures = [executor.submit(self.stage, *item, area) for item in items]
        wait(futures)
        errors = [e for f in futures if (e := f.exception()) is not None]
        if errors:
            self.unstage(f.result() for f in futures if f.exception() is None)
            raise errors[0]
        return [f.result() for f in futures]

    def write(self, relative: str, data: bytes) -> Path:
        """Write (or replace) the file at ``relative`` atomically; returns its path."""
        target = self.absolute(relative)
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(self._write_temporary(data), target)
        return target

    def _write_temporary(self, data: bytes) -> Path:  # one file, flushed on its own
        temporary = self._temporary()
        with open(temporary, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        return temporary

    def put_stream(
        self, source: BinaryIO, extension: str, area: str
    ) -> tuple[StoredFile, str, int]:
        """Copy a stream into the store, hashing it on the way; returns (file, sha256, size)."""
        temporary = self._temporary()
        digest, size = hashlib.sha256(), 0
        try:
            with open(temporary, "wb") as handle:
                while chunk := source.read(CHUNK):
                    digest.update(chunk)
                    size += len(chunk)
                    handle.write(chunk)
                handle.flush()
                os.fsync(handle.fileno())
        except BaseException:
            temporary.unlink(missing_ok=True)
            raise
        sha256 = digest.hexdigest()
        return self._install(temporary, self.relative_path(area, sha256, extension)), sha256, size

    def discard(self, files: Iterable[StoredFile], in_use: Collection[str] = ()) -> None:
        """Remove the files an aborted write created, except those a committed row now uses."""
        for stored in files:
            if stored.created and stored.path not in in_use:
                (self.home / stored.path).unlink(missing_ok=True)

    def sweep_orphans(
        self, areas: Iterable[str], known: set[str], older_than_s: float = 3600.0
    ) -> list[str]:
        """Remove files of ``areas`` that no row names (a crash between rename and commit).

        Only files older than ``older_than_s`` are touched, so uploads in flight in another
        process are safe. Returns the removed relative paths.
        """
        cutoff = time.time() - older_than_s
        removed = []
        for area in areas:
            root = self.home / area
            if not root.is_dir():
                continue
            for path in root.rglob("*"):
                relative = path.relative_to(self.home).as_posix()
                if path.is_file() and relative not in known and path.stat().st_mtime < cutoff:
                    path.unlink()
                    removed.append(relative)
        for stale in self.tmp.glob("*.part") if self.tmp.is_dir() else ():
            if stale.stat().st_mtime < cutoff:
                stale.unlink()
        return removed


def _fsync(path: Path) -> None:
    """Flush a file, or a directory's entries, to disk."""
    descriptor = os.open(path, os.O_RDONLY)
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)


def _created_parents(directory: Path, home: Path) -> list[Path]:
    """Create ``directory`` (and missing parents under home); returns the directories whose
    entries changed: the parents of every directory created here."""
    missing = []
    while not directory.exists() and directory != home:
        missing.append(directory)
        directory = directory.parent
    for path in reversed(missing):
        path.mkdir(exist_ok=True)
    return [path.parent for path in missing]
