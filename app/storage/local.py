"""The home folder backend of ``Storage``: content-addressed files under WELDPOOL_HOME, written
atomically, removed by one collector.

A file is written to a temporary name, flushed to disk, then renamed into place, and only then is
its row committed. For a whole request this is two steps: ``stage`` writes and flushes each new
file (in the ingest's disk threads, as soon as it is checked), ``install_many`` renames them all
into place and flushes the directories that received them, so the rows committed next never name
a file the disk could lose.

A claim refreshes the file's modification time (or is the write itself), and ``collect`` moves a
file aside before it looks at the claim, so a claim made while it looks is seen (the claimer
finds the name gone and writes the file again). ``discard`` removes an aborted write's files by
the exact claim time it wrote. Deletions collect the files their rows named at once; the
collector thread (``FileCollector``) and ``serve``'s start-up sweep the rest: files whose claim
was too fresh, and files a crash left between rename and commit.

An object store composes over one of these as its cache (``durable=False``: home's files are then
copies, not flushed).
"""

from __future__ import annotations

import os
import tempfile
import time
import uuid
from collections.abc import Collection, Iterable, Sequence
from concurrent.futures import Executor
from pathlib import Path
from typing import BinaryIO

from app.core.errors import MissingFile
from app.storage.protocol import (
    DEFAULT_GRACE_S,
    PART_LIFETIME_S,
    StagedFile,
    StoredFile,
    Unclaimed,
)
from app.storage.writes import (
    DISK_TASKS,
    collect_unclaimed,
    content_path,
    copy_hashed,
    discard_created,
    parts,
    stage_all,
)

CLAIM_SLACK_NS = 2_000_000_000
"""How fresh a claim must read back (2 s; the grace period is at least a minute)."""
_ASIDE = ".collect"  # a file the collector moved aside while it looks at its claim


class LocalStorage:
    """``Storage`` in one home directory: content-addressed files, claimed by their
    modification time, flushed before their rows commit (``durable``)."""

    remote: str | None = None
    """Home alone: no store besides it."""

    def __init__(
        self, home: Path, grace_s: float = DEFAULT_GRACE_S, *, durable: bool = True
    ) -> None:
        self.home = home.resolve()
        self.tmp = self.home / "tmp"
        self.grace_s = grace_s
        self.durable = durable
        """Whether home's files are the durable copy (flushed before their rows commit); an
        object store's cache is not (the bucket's copy is)."""

    def check(self) -> None:
        """Raise ConfigurationError when the store cannot be used (home alone: always can)."""

    def problem(self, *, named: bool = False) -> str | None:
        """Why the store cannot be used right now, in one sentence, or None (``/health``):
        here, that home cannot be written (``named``: a remote store's sentence names it)."""
        try:
            self.tmp.mkdir(parents=True, exist_ok=True)
            with tempfile.NamedTemporaryFile(dir=self.tmp, prefix="health-"):
                pass
        except OSError as exc:
            return (
                f"WELDPOOL_HOME cannot be written ({exc.strerror or type(exc).__name__}); give "
                "the service a writable home folder."
            )
        return None

    # --- shared files that are not content-addressed: model folders, exports, imports ------
    # In home alone these are plain files that every process reads already.

    def fetch(self, relative: str) -> Path:
        """The local path of a stored file, read from the shared store first when this
        machine does not have it (here: it is home's)."""
        return self.absolute(relative)

    def folder(self, relative: str) -> Path | None:
        """A stored folder (a model version's), complete on this machine; None when absent."""
        path = self.absolute(relative)
        return path if path.is_dir() else None

    def has_folder(self, relative: str) -> bool:
        """Whether a stored folder exists, without fetching it."""
        return self.absolute(relative).is_dir()

    def publish(self, relative: str, names: Iterable[str] | None = None) -> None:
        """Make a file or folder written under home visible to every process of the instance
        (a no-op here: they share home); called before the row that names it is committed.
        ``names``: only those files of the folder changed."""

    def unpublish(self, relative: str) -> None:
        """Withdraw what ``publish`` shared (a no-op here; the caller removes the local copy)."""

    def share(self, relative: str, path: Path) -> None:
        """Upload a file of this machine's own cache (an embedding) for the instance's other
        machines under ``relative`` (a no-op here: they share home)."""

    def pull(self, relative: str, path: Path) -> bool:
        """Fetch what ``share`` uploaded under ``relative`` into ``path``; False when the store
        has none (always here: home is the store)."""
        return False

    def prune_published(self, area: str, older_than_s: float) -> int:
        """Remove shared files of ``area`` older than ``older_than_s`` (none here: home's own
        pruning covers them); returns how many went."""
        return 0

    def fetch_ahead(self, paths: Iterable[str]) -> None:
        """Start bringing these files into this machine's cache, to be read soon (an object
        store's GETs, several at once in the background); home's files are here already."""
        return None

    def existing(self, relative: str) -> Path:
        """The file behind a stored relative path, for reading it (fetched into the cache
        first on an object store); MissingFile when the store no longer holds it. The one
        place a lost file is found out: readers ask here, not ``absolute``."""
        path = self.fetch(relative)
        if not path.is_file():
            raise MissingFile(relative)
        return path

    def holds(self, relative: str) -> bool:
        """Whether the store holds the file ``relative`` (one look, no read)."""
        return self._held(relative)

    def lost(self, paths: Iterable[str]) -> set[str]:
        """Those of ``paths`` (files or folders) the store no longer holds, found without
        reading them (``weldpool doctor``)."""
        return {p for p in paths if not self._held(p)}

    def _held(self, relative: str) -> bool:
        try:
            return self.absolute(relative).exists()
        except ValueError:  # a row naming a path outside the store: nothing there to read
            return False

    def _claimed(self, relative: str) -> bool:
        """Claim stored content (``_claim``); False when it is not there."""
        return self._claim(self.home / relative)

    def absolute(self, relative: str) -> Path:
        """The file behind a stored relative path (never outside home)."""
        return self.local(relative)

    def local(self, relative: str) -> Path:
        """This machine's path for ``relative`` under home (never outside it), fetching nothing:
        the folders, caches and scratch files that are each machine's own."""
        path = (self.home / relative).resolve()
        if not path.is_relative_to(self.home):
            raise ValueError(f"{relative!r} is outside the store")
        return path

    def relative(self, path: Path) -> str:
        """A path under home as the store names it (``models/student-v3``)."""
        return path.resolve().relative_to(self.home).as_posix()

    def scratch(self) -> Path:
        """This machine's folder for temporary files (``tmp/`` under home), made if missing."""
        self.tmp.mkdir(parents=True, exist_ok=True)
        return self.tmp

    def temporary(self) -> Path:
        """A fresh name for a temporary file in ``scratch()`` (``*.part``, swept after a day)."""
        return self.scratch() / f"{uuid.uuid4().hex}.part"

    @staticmethod
    def _claim(final: Path) -> bool:
        """Mark a stored file as about to be named by a row (its modification time becomes
        now); False when it is not there (never stored, or collected)."""
        now = time.time_ns()
        try:
            os.utime(final, ns=(now, now))
            # The name is looked up before the inode is touched: had the collector moved the
            # file aside in between, the claim would land on the file it is about to remove.
            # So the file now at the name must carry a fresh claim (ours, or another writer's;
            # the slack is for filesystems that keep coarser times).
            return os.stat(final).st_mtime_ns >= now - CLAIM_SLACK_NS
        except FileNotFoundError:
            return False

    def _install(self, temporary: Path, relative: str) -> StoredFile:
        """Put a flushed temporary in place, or claim the same content when it is there."""
        final = self.home / relative
        for _ in range(8):  # another writer's file can appear (or go) between two looks
            if self._claim(final):
                break
            final.parent.mkdir(parents=True, exist_ok=True)
            claimed = time.time_ns()
            os.utime(temporary, ns=(claimed, claimed))  # the claim, before anyone can see it
            try:
                os.link(temporary, final)  # never replaces a file another writer put there
            except FileExistsError:
                continue  # written by another writer meanwhile: claim theirs
            temporary.unlink()
            return StoredFile(relative, created=True, claimed_ns=claimed)
        else:
            temporary.unlink()
            raise OSError(f"{relative} could neither be claimed nor written; check the store.")
        temporary.unlink()
        return StoredFile(relative, created=False)

    def put(self, data: bytes, sha256: str, extension: str, area: str = "frames") -> StoredFile:
        """Store ``data`` (whose hash the caller computed) unless the same content is there."""
        relative = content_path(area, sha256, extension)
        if self._claimed(relative):
            return StoredFile(relative, created=False)
        return self._install(self.write_temporary(data), relative)

    def stage(self, data: bytes, sha256: str, extension: str, area: str = "frames") -> StagedFile:
        """Write new content to a temporary name and flush it to disk; nothing is in the store
        until ``install_many``. Content already stored is claimed instead. Any thread may stage
        (fsync releases the GIL), so a request's files reach the disk while the rest of it is
        still being checked."""
        relative = content_path(area, sha256, extension)
        if self._claimed(relative):
            return StagedFile(relative, None)
        temporary = self.temporary()
        try:
            temporary.write_bytes(data)
            if self.durable:
                _fsync(temporary)
        except BaseException:
            temporary.unlink(missing_ok=True)
            raise
        return StagedFile(relative, temporary)

    def unstage(self, staged: Iterable[StagedFile]) -> None:
        """Remove staged temporaries that will not be installed (content already stored was
        only claimed: the collector sees to it)."""
        for item in staged:
            if item.temporary is not None:
                item.temporary.unlink(missing_ok=True)

    def install_many(
        self, staged: Sequence[StagedFile], executor: Executor | None = None
    ) -> list[StoredFile]:
        """Put staged files in place, then flush each directory that gained an entry once
        (in ``executor``'s threads when given), so a crash after this returns cannot lose a
        file or its name. On failure nothing of it is left: files it created (unless claimed
        since) and temporaries are removed."""
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
            if executor is None:
                list(map(_fsync, touched))
            else:  # a few tasks, not one per directory (a future costs more than its fsync)
                list(executor.map(_fsync_all, parts(list(touched), DISK_TASKS)))
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
        given (``DISK_TASKS`` parts); if any fails, the others' temporaries are removed and its
        error raised."""
        return stage_all(self, items, area, executor)

    def write(self, relative: str, data: bytes) -> Path:
        """Write (or replace) the file at ``relative`` atomically; returns its path."""
        target = self.absolute(relative)
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(self.write_temporary(data), target)
        return target

    def write_temporary(self, data: bytes) -> Path:
        """``data`` in a fresh temporary (flushed on its own when ``durable``)."""
        temporary = self.temporary()
        with open(temporary, "wb") as handle:
            handle.write(data)
            if self.durable:
                handle.flush()
                os.fsync(handle.fileno())
        return temporary

    def put_stream(
        self, source: BinaryIO, extension: str, area: str
    ) -> tuple[StoredFile, str, int]:
        """Copy a stream into a temporary, hashing it on the way, then ``put_file`` it;
        returns (file, sha256, size)."""
        temporary = self.temporary()
        sha256, size = copy_hashed(source, temporary)
        return self.put_file(temporary, sha256, extension, area), sha256, size

    def put_file(self, path: Path, sha256: str, extension: str, area: str) -> StoredFile:
        """Flush a file of ``scratch()`` (when ``durable``) and link it under its content name
        (the same inode: written once), or claim the same content when it is there; ``path``
        is removed either way, and when this fails."""
        relative = content_path(area, sha256, extension)
        try:
            if self._claimed(relative):
                path.unlink()
                return StoredFile(relative, created=False)
            if self.durable:
                _fsync(path)
            return self._install(path, relative)
        except BaseException:
            path.unlink(missing_ok=True)
            raise

    # --- removal: the one collector ----------------------------------------------------------

    def discard(self, files: Iterable[StoredFile], in_use: Collection[str] = ()) -> int:
        """Remove the files an aborted write created, except those a committed row names or
        another writer claimed since (their claim time is no longer the one this write put);
        returns how many went."""
        return discard_created(files, in_use, self._remove_if)

    def collect(self, paths: Iterable[str], in_use: Collection[str]) -> list[str]:
        """Remove the files of ``paths`` that no committed row names (``in_use``, read after
        the rows that named them were deleted) and nobody claimed within the grace period;
        returns those removed. The others stay for the next sweep."""
        return collect_unclaimed(paths, in_use, self.grace_s, self._remove_if)

    def _remove_if(self, relative: str, unclaimed: Unclaimed) -> bool:
        """Move the file aside, then remove it if its claim time says nobody claimed it; else
        put it back. A claim made while it is aside finds no file and writes it again. A file
        already claimed is never moved: a reader that was just handed it (a video's probe after
        its upload claimed the stored copy) must not find it gone for a moment."""
        try:
            final = self.absolute(relative)
            if not unclaimed(final.stat().st_mtime_ns):
                return False
        except (ValueError, FileNotFoundError):  # outside the store (never touched), or gone
            return False
        self.tmp.mkdir(parents=True, exist_ok=True)
        aside = self.tmp / f"{relative.replace('/', '~')}~{uuid.uuid4().hex}{_ASIDE}"
        try:
            os.rename(final, aside)
        except FileNotFoundError:
            return False
        try:
            if unclaimed(aside.stat().st_mtime_ns):
                aside.unlink()
                return True
        except FileNotFoundError:  # a start-up sweep put it back meanwhile
            return False
        _put_back(aside, final)
        return False

    def sweep_orphans(
        self, areas: Iterable[str], known: set[str], older_than_s: float | None = None
    ) -> list[str]:
        """Remove files of ``areas`` that no row names and nobody claimed for ``older_than_s``
        (the grace period by default): a crash between rename and commit, or a deletion's file
        whose claim was too fresh then. ``known`` must be read before the walk starts. Returns
        the removed relative paths."""
        cutoff_s = time.time() - (self.grace_s if older_than_s is None else older_than_s)
        for aside in self.tmp.glob(f"*{_ASIDE}") if self.tmp.is_dir() else ():
            if _changed_s(aside, "st_ctime") > time.time() - 60:
                continue  # a collector is looking at it now (or it is gone already)
            relative = aside.name.removesuffix(_ASIDE).rsplit("~", 1)[0].replace("~", "/")
            _put_back(aside, self.home / relative)  # a collector died while it looked
        removed = []
        cutoff = int(cutoff_s * 1e9)
        for area in areas:
            root = self.home / area
            if not root.is_dir():
                continue
            for path in root.rglob("*"):
                relative = path.relative_to(self.home).as_posix()
                if relative in known or not path.is_file():
                    continue
                if self._remove_if(relative, lambda ns: ns < cutoff):
                    removed.append(relative)
        self.sweep_temporaries()
        return removed

    def sweep_temporaries(self) -> None:
        """Remove temporaries (``tmp/*.part``) left a day ago or longer (and at least a grace
        period): a request's staged files that never got installed."""
        parts_cutoff_s = time.time() - max(PART_LIFETIME_S, self.grace_s)
        for stale in self.tmp.glob("*.part") if self.tmp.is_dir() else ():
            if _changed_s(stale, "st_mtime") < parts_cutoff_s:
                stale.unlink(missing_ok=True)


def _changed_s(path: Path, field: str) -> float:
    """A file's ``st_ctime`` or ``st_mtime``; now when it has gone (another sweep took it)."""
    try:
        return float(getattr(path.stat(), field))
    except FileNotFoundError:
        return time.time()


def _put_back(aside: Path, final: Path) -> None:
    """Return a file the collector moved aside (unless it was written again meanwhile)."""
    try:
        os.link(aside, final)
    except FileExistsError:
        pass
    except FileNotFoundError:
        return
    aside.unlink(missing_ok=True)


def _fsync_all(paths: Iterable[Path]) -> None:
    for path in paths:
        _fsync(path)


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
