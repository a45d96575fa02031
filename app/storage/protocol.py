"""What the service asks of a store, and what every backend promises: the ``Storage`` protocol.

The database holds metadata and relative paths; a store holds the files. Two backends keep the
same promises: ``LocalStorage`` (``app.storage.local``: the home folder) and ``ObjectStorage``
(``app.storage.s3``: an S3-compatible bucket, composed over a ``LocalStorage`` of home as its
bounded read cache). ``open_storage`` (``app.storage``) picks one from the settings.

- **Written whole before its row is committed.** A writer's file is complete and durable (flushed
  to disk, or uploaded) before the call that wrote it returns, so a committed row never names a
  file a crash could lose or a reader could see half written.
- **Content-addressed and claimed.** Frames, videos, masks and heatmaps are named by their hash
  (``<area>/ab/cd/<sha256><ext>``), so one file may be about to be named by a row that is not
  committed yet (the same content uploaded to another run, a label with a proposal's mask).
  Every writer therefore claims the file it will name: it writes it, or marks the content that
  is already there as claimed now.
- **Removed only by the collector, never from under a claim.** A file no committed row names is
  removed by ``collect`` (a deletion's files) or ``sweep_orphans`` (what a crash or a too-fresh
  claim left) only when nobody claimed it within the grace period (``WELDPOOL_FILE_GRACE_S``);
  a writer commits within seconds of its claim, far inside it. A write that fails before its
  commit removes only the files it created that nobody claimed since (``discard``).
- **One place finds a lost file out.** Readers ask ``existing``, which raises MissingFile.

Shared files that are not content-addressed (model folders, export zips, uploaded imports,
shared embeddings) are published by name; ``SHARED_AREAS`` says which areas every process of an
instance sees alike.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Iterable, Sequence
from concurrent.futures import Executor
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Protocol, runtime_checkable

CHUNK = 1024 * 1024
SHARED_AREAS = ("frames", "videos", "artefacts", "models", "exports", "imports")
"""What every process of an instance must see alike: content-addressed files (frames, videos,
masks and heatmaps), model folders, export zips and uploaded imports. The rest of home
(``cache/``, ``tmp/``, the embedded database and queue) belongs to one machine."""
EXPORTS_DIR = "exports"
"""Where export jobs leave their zip (``<home>/exports/<job id>.zip``), kept a day."""
DEFAULT_GRACE_S = 900.0
"""How long a claimed file is safe from the collector (``WELDPOOL_FILE_GRACE_S``): far longer than
any writer takes from its claim to its commit."""
PART_LIFETIME_S = 86_400.0
"""A request's staged temporary (``tmp/*.part``) is swept only after a day: a slow upload of
many files may hold its first ones long before it commits."""


@dataclass(frozen=True)
class StagedFile:
    """Content written whole (flushed, or uploaded) but not yet in the store under its name."""

    relative: str
    temporary: Path | None  # None: the store holds this content already (and it is claimed)
    uploaded_ns: int = 0  # an object store's: uploaded already, with this claim time


@dataclass(frozen=True)
class StoredFile:
    """A file in the store: its path relative to home, and whether this call created it (then
    ``claimed_ns`` is the exact claim time it wrote, which ``discard`` looks for)."""

    path: str
    created: bool
    claimed_ns: int = 0


Unclaimed = Callable[[int], bool]
"""The collector's test of a file's claim time (ns): True when it may go."""


@runtime_checkable
class Storage(Protocol):
    """Content-addressed files and published folders of one instance, read through this
    machine's home folder. Every path is relative to home, as the database holds it."""

    home: Path
    """This machine's home folder (resolved): the store itself, or the object store's cache."""
    grace_s: float
    """How long a claim keeps a file from the collector (``WELDPOOL_FILE_GRACE_S``)."""
    remote: str | None
    """Where shared files live besides home (``s3://bucket/prefix``); None: home alone."""

    # --- health -------------------------------------------------------------------------

    def check(self) -> None:
        """Raise ConfigurationError when the store cannot be used (at start-up)."""
        ...

    def problem(self, *, named: bool = False) -> str | None:
        """Why the store cannot be used right now, in one sentence, or None (``/health``);
        ``named``: the sentence may name the store's URL."""
        ...

    # --- content-addressed writes: whole before the row, claimed ------------------------

    def put(self, data: bytes, sha256: str, extension: str, area: str = "frames") -> StoredFile:
        """Store ``data`` (whose hash the caller computed), whole and durable before this
        returns, or claim the same content when it is there."""
        ...

    def stage(self, data: bytes, sha256: str, extension: str, area: str = "frames") -> StagedFile:
        """Write new content whole (flushed, or uploaded) ahead of ``install_many``, in the
        caller's thread; content already stored is claimed instead."""
        ...

    def stage_many(
        self,
        items: Sequence[tuple[bytes, str, str]],
        area: str = "frames",
        executor: Executor | None = None,
    ) -> list[StagedFile]:
        """``stage`` for many ``(data, sha256, extension)``, in ``executor``'s threads when
        given; if any fails, the others are unstaged and its error raised."""
        ...

    def unstage(self, staged: Iterable[StagedFile]) -> None:
        """Withdraw staged content that will not be installed (what it created alone)."""
        ...

    def install_many(
        self, staged: Sequence[StagedFile], executor: Executor | None = None
    ) -> list[StoredFile]:
        """Put staged files under their names, durable when this returns, so the rows
        committed next never name a file that can be lost; on failure nothing of it is left
        (files it created and nobody claimed since, and the temporaries, are removed)."""
        ...

    def put_stream(
        self, source: BinaryIO, extension: str, area: str
    ) -> tuple[StoredFile, str, int]:
        """Copy a stream into the store (never whole in memory), hashing it on the way, and
        claim it; returns (file, sha256, size)."""
        ...

    def put_file(self, path: Path, sha256: str, extension: str, area: str) -> StoredFile:
        """Move a whole file of ``scratch()`` (the store's filesystem; ``sha256`` computed by
        the caller as it was written) under its content name, written once, never copied: it
        is renamed into place (an object store uploads it once, in parts past its threshold,
        and keeps it as the cached copy), whole and durable before this returns; the same
        content stored already is claimed instead and the file removed. ``path`` is gone when
        this returns, also when it fails."""
        ...

    def write(self, relative: str, data: bytes) -> Path:
        """Write (or replace) this machine's file at ``relative`` atomically; returns its
        path (a file derived from stored content, which any machine can make again)."""
        ...

    # --- reads ------------------------------------------------------------------------

    def existing(self, relative: str) -> Path:
        """The file behind a stored relative path, for reading it (fetched into this machine's
        cache first where the store is remote); MissingFile when the store no longer holds it.
        The one place a lost file is found out."""
        ...

    def absolute(self, relative: str) -> Path:
        """This machine's path of a stored file (never outside home), a content-addressed one
        brought into the cache when the store is remote; it may not exist (``existing`` says
        so)."""
        ...

    def fetch(self, relative: str) -> Path:
        """The local path of a shared file (any of ``SHARED_AREAS``), read from the shared
        store first when this machine does not have it."""
        ...

    def fetch_ahead(self, paths: Iterable[str]) -> None:
        """Start bringing these files into this machine's cache, to be read soon (in the
        background; what goes wrong is met again by the read that wants them)."""
        ...

    def holds(self, relative: str) -> bool:
        """Whether the store holds the file ``relative`` for every machine (one look, no read)."""
        ...

    def lost(self, paths: Iterable[str]) -> set[str]:
        """Those of ``paths`` (files or folders) the store no longer holds, found without
        reading them (``weldpool doctor``)."""
        ...

    # --- this machine's own paths ---------------------------------------------------------

    def local(self, relative: str) -> Path:
        """This machine's path for ``relative`` under home (never outside it), fetching
        nothing: the folders, caches and scratch files that are each machine's own."""
        ...

    def relative(self, path: Path) -> str:
        """A path under home as the store names it (``models/student-v3``)."""
        ...

    def scratch(self) -> Path:
        """This machine's folder for temporary files (``tmp/`` under home), made if missing."""
        ...

    # --- shared files that are not content-addressed ---------------------------------------

    def folder(self, relative: str) -> Path | None:
        """A published folder (a model version's), complete on this machine; None when absent."""
        ...

    def has_folder(self, relative: str) -> bool:
        """Whether a published folder exists, without fetching it."""
        ...

    def publish(self, relative: str, names: Iterable[str] | None = None) -> None:
        """Make a file or folder written under home visible to every process of the instance,
        complete when this returns; called before the row that names it is committed.
        ``names``: only those files of the folder changed."""
        ...

    def unpublish(self, relative: str) -> None:
        """Withdraw what ``publish`` shared (the caller removes the local copy)."""
        ...

    def share(self, relative: str, path: Path) -> None:
        """Share a file of this machine's own cache (an embedding) with the instance's other
        machines under ``relative``."""
        ...

    def pull(self, relative: str, path: Path) -> bool:
        """Fetch what ``share`` shared under ``relative`` into ``path``; False when there is
        none (or home is the store, which every machine reads already)."""
        ...

    def prune_published(self, area: str, older_than_s: float) -> int:
        """Remove shared files of ``area`` older than ``older_than_s`` that home's own pruning
        does not reach; returns how many went."""
        ...

    # --- removal: the one collector -------------------------------------------------------

    def discard(self, files: Iterable[StoredFile], in_use: Collection[str] = ()) -> int:
        """Remove the files an aborted write created, except those a committed row names or
        another writer claimed since; returns how many went."""
        ...

    def collect(self, paths: Iterable[str], in_use: Collection[str]) -> list[str]:
        """Remove the files of ``paths`` that no committed row names (``in_use``, read after
        the rows that named them were deleted) and nobody claimed within the grace period;
        returns those removed. The others stay for the next sweep."""
        ...

    def sweep_orphans(
        self, areas: Iterable[str], known: set[str], older_than_s: float | None = None
    ) -> list[str]:
        """Remove files of ``areas`` that no row names (``known``, read before the sweep
        starts) and nobody claimed for ``older_than_s`` (the grace period by default): a
        crash's files, a deletion's whose claim was too fresh. Returns the removed paths."""
        ...
