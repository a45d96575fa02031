"""A multipart/form-data body read as it arrives, each file handed on the moment it is whole.

Starlette's ``request.form()`` returns only once the whole body is in, each file spooled to a
temporary file; frame upload instead hands every file to its checks while the rest of the body
is still arriving, so receiving and checking overlap. A video upload asks for its file spooled
(``spool``): held in memory up to that size, then written to a temporary file off the event
loop, and handed on as a file object; or (``spool_dir``) written straight to a named file in
that folder (a ``ScratchSpool``, hashed on the way when ``hashed``), for a caller that moves it
into its final place on the same filesystem (a label import's zip, a video: written once, never
copied). Both uploads read their forms here; the parsing
itself is python-multipart's (Starlette's parser too); this module keeps Starlette's limits
and adds the file names exactly as the client sent them.
"""

from __future__ import annotations

import codecs
import email.message
import re
import tempfile
from collections.abc import AsyncIterable, AsyncIterator, Callable, Mapping
from contextlib import asynccontextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import anyio
from python_multipart.exceptions import MultipartParseError
from python_multipart.multipart import MultipartParser, MultipartState, parse_options_header
from starlette.concurrency import run_in_threadpool
from starlette.requests import Request

from app.core.bounds import MAX_ID
from app.core.errors import InvalidInputError
from app.storage.spool import ScratchSpool

MAX_FIELD_BYTES = 1024 * 1024
"""The largest plain (non-file) field: a form's fields are ids and options, never data."""


def client_file_name(content_disposition: str) -> str | None:
    """A part's file name exactly as the client sent it (None when it names no file).

    python-multipart keeps only what follows the last backslash of a name that looks like a
    Windows path (``C:\\Windows\\x.png`` becomes ``x.png``), which would slip past the rule that
    names with path parts are refused; so the header is read here with the standard library.
    """
    header = email.message.Message()
    header["content-disposition"] = content_disposition
    name = header.get_filename()
    return None if name is None else str(name)


@dataclass
class _Part:
    header_name: bytes = b""
    header_value: bytes = b""
    disposition: bytes = b""
    field_name: str = ""
    file_name: str | None = None
    data: list[bytes] = field(default_factory=list)
    size: int = 0
    spool: Any = None  # a spooled part's SpooledTemporaryFile or ScratchSpool
    written: int = 0  # bytes of it written to its spool so far


class StreamedForm:
    """Plain fields of a multipart body; its files go to ``on_file(field, name, data)``: the
    bytes, or with ``spool`` a file object (rewound; ``close`` closes them all), with
    ``spool_dir`` a ``ScratchSpool`` there from the first byte, hashed as it is written when
    ``hashed`` (``close`` removes those not moved).

    ``limit_hint`` ends the too-many-files sentence (the setting that sets ``max_files``)."""

    def __init__(
        self,
        on_file: Callable[[str, str, Any], None],
        *,
        max_files: int,
        max_fields: int,
        charset: str = "utf-8",
        spool: int | None = None,
        limit_hint: str = " (WELDPOOL_MAX_FILES_PER_REQUEST); send them in several requests",
        spool_dir: Path | None = None,
        hashed: bool = False,
    ) -> None:
        self.fields: dict[str, str] = {}
        self._on_file = on_file
        self._max_files, self._max_fields = max_files, max_fields
        self._files = self._field_count = 0
        self._charset = charset
        self._part = _Part()
        self._spool_size, self._limit_hint = spool, limit_hint
        self._spool_dir, self._hashed = spool_dir, hashed
        if spool_dir is not None:
            self._spool_size = 0  # on disk from the first byte
        self._spools: list[IO[bytes] | ScratchSpool] = []
        self._pending: list[tuple[_Part, bytes]] = []  # spooled data not yet written
        self._finished: list[_Part] = []  # spooled parts whole, to hand on once written

    async def read(self, content_type: str, body: AsyncIterable[bytes]) -> None:
        """Parse ``body``; one-sentence InvalidInputError for a malformed or oversized form."""
        if not content_type.startswith("multipart/form-data"):
            raise InvalidInputError("Send the upload as multipart/form-data.")
        _, params = parse_options_header(content_type)
        boundary = params.get(b"boundary")
        if not boundary:
            raise InvalidInputError("The multipart body has no boundary in its Content-Type.")
        charset = params.get(b"charset", b"utf-8").decode("latin-1")
        try:
            self._charset = codecs.lookup(charset).name
        except LookupError:
            self._charset = "latin-1"
        parser = MultipartParser(
            boundary,
            {
                "on_part_begin": self._begin,
                "on_header_field": self._header_field,
                "on_header_value": self._header_value,
                "on_header_end": self._header_end,
                "on_headers_finished": self._headers_finished,
                "on_part_data": self._data,
                "on_part_end": self._end,
            },
        )
        try:
            async for chunk in body:
                parser.write(chunk)
                await self._write_spooled()
            parser.finalize()
            await self._write_spooled()
        except MultipartParseError as exc:
            raise InvalidInputError(f"The multipart body is malformed ({exc}).") from None
        if parser.state != MultipartState.END:
            raise InvalidInputError("The multipart body ends before its closing boundary.")

    async def _write_spooled(self) -> None:
        """Spooled data into its files (in a worker thread once a file is on disk), then the
        parts that are whole handed on."""
        pending, self._pending = self._pending, []
        for part, data in pending:
            part.written += len(data)
            if part.written > (self._spool_size or 0):  # on disk by now: a thread waits for it
                await run_in_threadpool(part.spool.write, data)
            else:
                part.spool.write(data)
        finished, self._finished = self._finished, []
        for part in finished:
            part.spool.seek(0)
            self._on_file(part.field_name, part.file_name or "", part.spool)

    def close(self) -> None:
        """Close every spooled file this form made; remove those in ``spool_dir`` that were
        not moved away."""
        for spool in self._spools:
            spool.close()
            if self._spool_dir is not None:
                Path(spool.name).unlink(missing_ok=True)

    def _decode(self, value: bytes) -> str:
        try:
            return value.decode(self._charset)
        except UnicodeDecodeError:
            return value.decode("latin-1")

    def _begin(self) -> None:
        self._part = _Part()

    def _header_field(self, data: bytes, start: int, end: int) -> None:
        self._part.header_name += data[start:end]

    def _header_value(self, data: bytes, start: int, end: int) -> None:
        self._part.header_value += data[start:end]

    def _header_end(self) -> None:
        if self._part.header_name.lower() == b"content-disposition":
            self._part.disposition = self._part.header_value
        self._part.header_name = self._part.header_value = b""

    def _headers_finished(self) -> None:
        part = self._part
        _, options = parse_options_header(part.disposition)
        if b"name" not in options:
            raise InvalidInputError('Each part\'s Content-Disposition must give its "name".')
        part.field_name = self._decode(options[b"name"])
        raw_name = client_file_name(self._decode(part.disposition))
        if b"filename" in options or raw_name is not None:  # also a name only as filename*
            self._files += 1
            if self._files > self._max_files:
                raise InvalidInputError(
                    f"Too many files in one request: at most {self._max_files}{self._limit_hint}."
                )
            part.file_name = raw_name if raw_name is not None else ""
            if self._spool_dir is not None:
                part.spool = ScratchSpool(self._spool_dir, hashed=self._hashed)
                self._spools.append(part.spool)
            elif self._spool_size is not None:
                part.spool = tempfile.SpooledTemporaryFile(max_size=self._spool_size)  # noqa: SIM115 (closed by close())
                self._spools.append(part.spool)
        else:
            self._field_count += 1
            if self._field_count > self._max_fields:
                raise InvalidInputError(f"Too many form fields: at most {self._max_fields}.")

    def _data(self, data: bytes, start: int, end: int) -> None:
        part = self._part
        part.size += end - start
        if part.file_name is None and part.size > MAX_FIELD_BYTES:
            raise InvalidInputError(f"The form field {part.field_name!r} is larger than 1 MB.")
        if part.spool is not None:
            self._pending.append((part, bytes(data[start:end])))
        else:
            part.data.append(data[start:end])

    def _end(self) -> None:
        part = self._part
        if part.spool is not None:
            self._finished.append(part)
            return
        data = b"".join(part.data)
        if part.file_name is None:
            self.fields[part.field_name] = self._decode(data)
        else:
            self._on_file(part.field_name, part.file_name, data)


def openapi_form(fields: dict[str, Any], required: list[str]) -> dict[str, Any]:
    """An OpenAPI request body for a multipart form parsed by hand (to set its limits)."""
    return {
        "requestBody": {
            "required": True,
            "content": {
                "multipart/form-data": {
                    "schema": {"type": "object", "properties": fields, "required": required}
                }
            },
        }
    }


def optional_int(form: Mapping[str, Any], name: str, default: int | None = None) -> int | None:
    value = form.get(name)
    if value is None or value == "":
        return default
    if not isinstance(value, str) or not re.fullmatch(r"\s*-?[0-9]+\s*", value):
        raise InvalidInputError(f"{name} must be an integer.")
    number = int(value)
    if abs(number) > MAX_ID:
        raise InvalidInputError(f"{name} must be at most {MAX_ID}.")
    return number


SPOOL_BYTES = 1024 * 1024
"""A spooled file part is held in memory up to this size, then written to a temporary file."""


@asynccontextmanager
async def one_spooled_file(
    request: Request,
    what: str,
    max_fields: int = 16,
    spool_dir: Path | None = None,
    *,
    hashed: bool = False,
) -> AsyncIterator[tuple[dict[str, str], str, Any]]:
    """A form of one file part (``file``, spooled) and some fields, read from ``request``:
    yields the fields, the file's client name and the file; the spool is removed on the way
    out (unless the caller moved it), also when the request is cancelled. ``what`` names the
    file in the errors; ``spool_dir``: the file is written to a ``ScratchSpool`` there, never
    held in memory, for the caller to move into place (``hashed``: its ``sha256`` known once it
    is whole; ``StreamedForm``)."""
    uploads: list[tuple[str, Any]] = []
    form = StreamedForm(
        lambda field, name, file: uploads.append((name, file)) if field == "file" else None,
        max_files=1,
        max_fields=max_fields,
        spool=SPOOL_BYTES,
        limit_hint=f"; send one {what} per request",
        spool_dir=spool_dir,
        hashed=hashed,
    )
    try:
        await form.read(request.headers.get("content-type", ""), request.stream())
        if not uploads:
            raise InvalidInputError(f"The request has no `file` part; attach one {what}.")
        name, upload = uploads[0]
        yield form.fields, name, upload
    finally:
        with anyio.CancelScope(shield=True):
            await run_in_threadpool(form.close)
