"""Where imported labels come from: a folder, a zip archive, or one annotation file.

Every path inside a source is relative, POSIX-style and checked: an entry that would leave the
source (``../x.png``, an absolute path, a drive letter, a link pointing out of the folder) is
refused by name and never read. A zip is read entry by entry with its declared sizes bounded
(``MAX_ENTRY_BYTES``, ``MAX_RATIO``) and all of its entries counted against one budget
(``expansion_budget``) before any is read, and no entry is read past its declared size, so a
zip bomb costs what its headers admit to and no more. Two entries of one name are both refused.
"""

from __future__ import annotations

import json
import posixpath
import re
import zipfile
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any

from weldpool_core.errors import InvalidInputError

MAX_ENTRIES = 200_000
"""Most files one import may hold (a million-frame lab splits its import)."""
MAX_ENTRY_BYTES = 512 * 1024 * 1024
"""Largest single file of an import (an annotation file of 1,000,000 polygons is ~300 MB)."""
MAX_TOTAL_BYTES = 64 * 1024**3
"""Most bytes all files of one import may expand to."""
FREE_EXPANSION = 64 * 1024**2
"""Bytes any zip may expand to, however small (its entries' ratio aside)."""
MAX_RATIO = 200
"""Largest compression ratio a zip entry over 1 MiB may declare: PNG and JPEG frames barely
compress, JSON compresses ~10×; a bomb's entries compress 1000× and more."""
ENTRY_ERRORS = (
    zipfile.BadZipFile,  # a bad CRC or header
    zlib.error,  # a damaged deflate stream
    RuntimeError,  # an encrypted entry (zipfile asks for a password)
    NotImplementedError,  # a compression method zipfile lacks
    OSError,
    EOFError,
    ValueError,
)
"""What reading one damaged zip entry raises: that entry is refused, the rest is read."""
_DRIVE = re.compile(r"^[A-Za-z]:")


@dataclass(frozen=True)
class Refusal:
    """One item that was not imported, and why, in one sentence."""

    item: str
    reason: str


def clean_name(name: str) -> str | None:
    """``name`` as a relative POSIX path inside the source, or None when it would leave it."""
    name = name.replace("\\", "/")
    if not name or name.startswith("/") or _DRIVE.match(name) or "\x00" in name:
        return None
    parts = PurePosixPath(name).parts
    if any(part == ".." for part in parts):
        return None
    cleaned = posixpath.normpath(name)
    return None if cleaned in (".", "") else cleaned


class Source:
    """The files of one import by their path inside it, read on demand.

    ``primary`` is the annotation file the user pointed at (a single file, or None for a folder
    or a zip). ``refused`` lists entries that were not admitted (unsafe paths, oversized or
    over-compressed entries, two entries of one name)."""

    def __init__(
        self,
        files: dict[str, Callable[[], bytes]],
        name: str,
        refused: list[Refusal],
        primary: str | None = None,
        closer: Callable[[], None] | None = None,
    ) -> None:
        self._files = files
        self.name = name
        self.refused = refused
        self.primary = primary
        self._closer = closer
        self._by_base: dict[str, list[str]] = {}
        for path in files:
            self._by_base.setdefault(posixpath.basename(path).lower(), []).append(path)

    @property
    def names(self) -> list[str]:
        return sorted(self._files)

    def __contains__(self, name: str) -> bool:
        return name in self._files

    def read(self, name: str) -> bytes:
        return self._files[name]()

    def read_json(self, name: str) -> Any:
        """The JSON document in ``name``.

        Raises:
            InvalidInputError: the file cannot be read, or is not valid JSON (including JSON
                nested deeper than the parser's recursion allows).
        """
        try:
            return json.loads(self.read(name))
        except (ValueError, UnicodeDecodeError, RecursionError):
            raise InvalidInputError("The file is not valid JSON.") from None

    def find(self, name: str, beside: str = "") -> str | None:
        """The file an annotation names: ``name`` relative to the annotation file's folder
        (``beside``), then from the source's root, then under ``images/``, then the only file
        with that base name anywhere; None when there is none.

        Raises:
            InvalidInputError: only its base name matches, and several files have it.
        """
        cleaned = clean_name(name)
        if cleaned is None:
            return None
        folder = posixpath.dirname(beside)
        for candidate in (
            posixpath.normpath(posixpath.join(folder, cleaned)) if folder else cleaned,
            cleaned,
            posixpath.join("images", cleaned),
            posixpath.join(folder, "images", cleaned) if folder else "",
        ):
            if candidate and candidate in self._files:
                return candidate
        matches = self._by_base.get(posixpath.basename(cleaned).lower(), [])
        if len(matches) > 1:
            shown = ", ".join(sorted(matches)[:3]) + (", …" if len(matches) > 3 else "")
            raise InvalidInputError(
                f"The name {name!r} is ambiguous: {len(matches)} files of the import have it "
                f"({shown}); name the image with its folder."
            )
        return matches[0] if matches else None

    def close(self) -> None:
        if self._closer is not None:
            self._closer()


def _zip_source(path: Path, name: str) -> Source:
    try:
        archive = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError) as exc:
        raise InvalidInputError(f"The file is not a readable zip archive ({exc}).") from None
    infos = [info for info in archive.infolist() if not info.is_dir()]
    if len(infos) > MAX_ENTRIES:
        archive.close()
        raise InvalidInputError(f"The archive holds more than {MAX_ENTRIES:,} files; split it.")
    files: dict[str, Callable[[], bytes]] = {}
    refused: list[Refusal] = []
    named: dict[str, int] = {}
    sizes: dict[str, int] = {}
    for info in infos:
        cleaned = clean_name(info.filename)
        if cleaned is None:
            refused.append(Refusal(info.filename, "The path leaves the archive; it is not read."))
            continue
        named[cleaned] = named.get(cleaned, 0) + 1
        problem = _size_problem(info)
        if problem:
            refused.append(Refusal(info.filename, problem))
            continue
        files[cleaned] = _entry_reader(archive, info)
        sizes[cleaned] = info.file_size
    for cleaned, count in named.items():
        if count > 1:
            files.pop(cleaned, None)
            refused.append(
                Refusal(
                    cleaned,
                    f"The archive holds {count} entries of this name; none is read (keep one).",
                )
            )
    try:
        _check_expansion(sum(sizes[n] for n in files), path.stat().st_size)
    except InvalidInputError:
        archive.close()
        raise
    return Source(files, name, refused, closer=archive.close)


def expansion_budget(stored: int) -> int:
    """The most bytes the files of an import stored in ``stored`` bytes may expand to: what
    ``MAX_RATIO`` allows (each entry's rule, over the whole archive), at least
    ``FREE_EXPANSION``, at most ``MAX_TOTAL_BYTES``."""
    return min(MAX_TOTAL_BYTES, max(FREE_EXPANSION, MAX_RATIO * stored))


def _check_expansion(total: int, stored: int) -> None:
    """Refuse an import whose files expand past ``expansion_budget``, before any is read."""
    if total <= expansion_budget(stored):
        return
    if total > MAX_TOTAL_BYTES:
        raise InvalidInputError(
            f"The import expands to more than {MAX_TOTAL_BYTES // 1024**3} GiB; split it."
        )
    raise InvalidInputError(
        f"The archive's {stored / 2**20:,.1f} MiB expand to {total / 2**20:,.0f} MiB "
        f"({total / max(stored, 1):,.0f}×, a zip bomb?); it is not read."
    )


def _size_problem(info: zipfile.ZipInfo) -> str | None:
    if info.file_size > MAX_ENTRY_BYTES:
        return f"The file expands to more than {MAX_ENTRY_BYTES // 1024**2} MiB; it is not read."
    ratio = info.file_size / max(info.compress_size, 1)
    if info.file_size > 1024 * 1024 and ratio > MAX_RATIO:
        return f"The file is compressed {ratio:,.0f}× (a zip bomb?); it is not read."
    return None


def _entry_reader(archive: zipfile.ZipFile, info: zipfile.ZipInfo) -> Callable[[], bytes]:
    def read() -> bytes:
        try:
            with archive.open(info) as handle:
                data = handle.read(info.file_size + 1)
        except ENTRY_ERRORS as exc:
            raise InvalidInputError(f"The archive entry cannot be read ({exc}).") from None
        if len(data) != info.file_size:
            raise InvalidInputError("The archive entry is not the size its header says.")
        return data

    return read


def _folder_source(root: Path, name: str, primary: str | None = None) -> Source:
    files: dict[str, Callable[[], bytes]] = {}
    refused: list[Refusal] = []
    resolved = root.resolve()
    total = 0
    for path in sorted(root.rglob("*")):
        if len(files) >= MAX_ENTRIES:
            raise InvalidInputError(f"The folder holds more than {MAX_ENTRIES:,} files; split it.")
        relative = path.relative_to(root).as_posix()
        if not path.is_file():
            continue
        if not path.resolve().is_relative_to(resolved):
            refused.append(Refusal(relative, "The file links outside the folder; it is not read."))
            continue
        size = path.stat().st_size
        if size > MAX_ENTRY_BYTES:
            refused.append(Refusal(relative, "The file is too large to import."))
            continue
        total += size
        _check_expansion(total, MAX_TOTAL_BYTES)  # a folder's files are what they are
        files[relative] = path.read_bytes
    return Source(files, name, refused, primary)


def open_source(path: str | Path, name: str | None = None) -> Source:
    """A folder, a zip archive, or one annotation file (with its folder's files beside it)."""
    path = Path(path)
    label = name or path.name
    if path.is_dir():
        return _folder_source(path, label)
    if not path.is_file():
        raise InvalidInputError(f"{path} does not exist.")
    if _is_zip(path):
        return _zip_source(path, label)
    return _folder_source(path.parent, label, primary=path.name)


def is_zip(head: bytes) -> bool:
    """Whether a file's first 4 bytes open a zip archive (an empty one too)."""
    return head.startswith(b"PK\x03\x04") or head == b"PK\x05\x06"


def _is_zip(path: Path) -> bool:
    with open(path, "rb") as handle:
        return is_zip(handle.read(4))


def open_upload(path: str | Path, name: str) -> Source:
    """An uploaded file: a zip archive, or one annotation file on its own (its images are
    already stored)."""
    path = Path(path)
    if _is_zip(path):
        return _zip_source(path, name)
    cleaned = clean_name(name.replace("\\", "/").rsplit("/", 1)[-1]) or "annotations"
    return Source({cleaned: path.read_bytes}, name, [], primary=cleaned)
