"""The upload's multipart body read as it arrives (app.frames.multipart) and the checks it
starts (ingest.FrameChecks): each file is handed on, and its check begun, before the body
has ended."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import AsyncIterator

import pytest

from app.core.errors import InvalidInputError
from app.frames import ingest
from app.frames.multipart import StreamedForm
from app.storage import LocalStorage
from tests.helpers import image_bytes, wait_for


def _part(name: str, data: bytes, file_name: str | None = None) -> bytes:
    disposition = f'form-data; name="{name}"' + (
        f'; filename="{file_name}"' if file_name is not None else ""
    )
    return f"--b\r\nContent-Disposition: {disposition}\r\n\r\n".encode() + data + b"\r\n"


def _read(chunks: list[bytes], **limits: int) -> tuple[StreamedForm, list[tuple[str, str, bytes]]]:
    files: list[tuple[str, str, bytes]] = []
    form = StreamedForm(
        lambda *file: files.append(file),
        max_files=limits.get("max_files", 10),
        max_fields=limits.get("max_fields", 10),
    )

    async def body() -> AsyncIterator[bytes]:
        for chunk in chunks:
            yield chunk

    asyncio.run(form.read("multipart/form-data; boundary=b", body()))
    return form, files


def test_each_file_is_handed_on_before_the_body_ends() -> None:
    first, second = image_bytes(seed=1), image_bytes(seed=2)
    files: list[tuple[str, str, bytes]] = []
    seen_before_the_rest: list[list[str]] = []
    form = StreamedForm(lambda *file: files.append(file), max_files=10, max_fields=10)

    async def body() -> AsyncIterator[bytes]:
        yield _part("sequence_id", b"7")
        yield _part("files", first, "a.png")
        yield b"--b\r\n"  # the next boundary: the first file is whole
        seen_before_the_rest.append([name for _, name, _ in files])
        yield _part("files", second, "b.png")[5:]
        yield b"--b--\r\n"

    asyncio.run(form.read("multipart/form-data; boundary=b", body()))
    assert seen_before_the_rest == [["a.png"]]
    assert files == [("files", "a.png", first), ("files", "b.png", second)]
    assert form.fields == {"sequence_id": "7"}


def test_names_are_kept_as_sent_and_fields_are_plain_text() -> None:
    windows = "C:\\Windows\\x.png"
    form, files = _read(
        [_part("files", b"1", windows), _part("note", "s\u00e9am".encode()), b"--b--\r\n"]
    )
    assert files == [("files", windows, b"1")]  # python-multipart alone would give 'x.png'
    assert form.fields == {"note": "s\u00e9am"}
    rfc2231 = (
        b"--b\r\nContent-Disposition: form-data; name=\"files\"; filename*=UTF-8''n%C3%A4me.png"
    )
    _, files = _read([rfc2231 + b"\r\n\r\n2\r\n", b"--b--\r\n"])
    assert files == [("files", "n\u00e4me.png", b"2")]  # a name given only as filename*


@pytest.mark.parametrize(
    ("chunks", "limits", "message"),
    [
        (
            [_part("files", b"1", "a"), _part("files", b"2", "b"), b"--b--\r\n"],
            {"max_files": 1},
            "Too many files in one request: at most 1",
        ),
        (
            [_part("x", b"1"), _part("y", b"2"), b"--b--\r\n"],
            {"max_fields": 1},
            "Too many form fields",
        ),
        ([_part("note", b"x" * (1024 * 1024 + 1)), b"--b--\r\n"], {}, "larger than 1 MB"),
        ([b"--b\r\nContent-Disposition: form-data\r\n\r\nx\r\n--b--\r\n"], {}, '"name"'),
        ([_part("files", b"1", "a")], {}, "ends before its closing boundary"),
    ],
)
def test_malformed_or_oversized_forms_are_one_sentence(chunks, limits, message) -> None:
    with pytest.raises(InvalidInputError, match=message) as caught:
        _read(chunks, **limits)
    assert caught.value.message.endswith(".")


def test_a_body_that_is_not_multipart_or_has_no_boundary() -> None:
    form = StreamedForm(lambda *file: None, max_files=1, max_fields=1)

    async def empty() -> AsyncIterator[bytes]:
        yield b""

    with pytest.raises(InvalidInputError, match="multipart/form-data"):
        asyncio.run(form.read("application/json", empty()))
    with pytest.raises(InvalidInputError, match="no boundary"):
        asyncio.run(form.read("multipart/form-data", empty()))


def test_a_file_is_checked_and_staged_while_the_caller_goes_on(
    tmp_path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``FrameChecks.add`` returns at once: the check runs in the pool (here it waits for the
    caller to go on, which it could not if add ran it), and results() has it staged."""
    started, release = threading.Event(), threading.Event()
    real = ingest.check_frame_file

    def held(*args, **kwargs):  # type: ignore[no-untyped-def]
        started.set()
        assert release.wait(timeout=10), "the caller was blocked by the check"
        return real(*args, **kwargs)

    monkeypatch.setattr(ingest, "check_frame_file", held)
    storage = LocalStorage(tmp_path)
    checks = ingest.FrameChecks(storage, max_pixels=10**6)
    checks.add(ingest.IncomingFile("a.png", image_bytes(seed=5)))
    checks.add(ingest.IncomingFile("copy.png", image_bytes(seed=5)))
    assert started.wait(timeout=10)  # the check began while add's caller went on…
    release.set()  # …and the caller is free to release it
    first, copy = checks.results()
    assert isinstance(first, ingest.CheckedFrame) and first.name == "a.png"
    assert first.staged is not None and first.staged.temporary is not None
    assert first.staged.temporary.read_bytes() == image_bytes(seed=5)  # on disk already
    assert isinstance(copy, ingest.CheckedFrame) and copy.staged is None  # one file a content
    checks.discard()
    assert not first.staged.temporary.exists()


def test_a_file_is_staged_while_it_is_checked_and_withdrawn_when_refused(
    tmp_path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A file whose header names an image format is staged (an object store's upload) while
    its check runs, not after it; one the check refuses leaves nothing staged."""
    release = threading.Event()
    real = ingest.check_frame_file
    storage = LocalStorage(tmp_path)

    def held(*args, **kwargs):  # type: ignore[no-untyped-def]
        assert release.wait(timeout=10)
        return real(*args, **kwargs)

    monkeypatch.setattr(ingest, "check_frame_file", held)
    checks = ingest.FrameChecks(storage, max_pixels=10**6)
    good, cut = image_bytes(seed=6), image_bytes(seed=7)[:200]  # both begin as PNGs
    checks.add(ingest.IncomingFile("a.png", good))
    checks.add(ingest.IncomingFile("cut.png", cut))
    wait_for(lambda: len(list(storage.tmp.glob("*.part"))) == 2, timeout=10)
    release.set()  # both were on disk while their checks were held
    first, refused = checks.results()
    assert isinstance(first, ingest.CheckedFrame) and first.staged is not None
    assert first.staged.temporary is not None and first.staged.temporary.read_bytes() == good
    assert isinstance(refused, ingest.Rejection) and "truncated" in refused.reason
    assert list(storage.tmp.glob("*.part")) == [first.staged.temporary]  # the cut one went
    checks.discard()
    assert not list(storage.tmp.glob("*.part"))


def test_a_spooled_file_arrives_whole_as_a_file_on_disk_and_closes_with_the_form() -> None:
    """A video's part (spool): held in memory up to the spool size, then on disk; handed on
    rewound, byte for byte, with its exact name; the form's fields beside it; closed by
    ``close``. Data split at every chunk boundary, the boundary itself split too."""
    video = bytes(range(256)) * 4096  # 1 MiB, four times the spool
    body = _part("every_nth", b"3") + _part("file", video, "C:\\runs\\a b.mp4") + b"--b--\r\n"
    files: list[tuple[str, str, object]] = []
    form = StreamedForm(lambda *file: files.append(file), max_files=1, max_fields=4, spool=2**18)

    async def chunks() -> AsyncIterator[bytes]:
        for start in range(0, len(body), 65_537):  # odd sizes: parts straddle the chunks
            yield body[start : start + 65_537]

    asyncio.run(form.read("multipart/form-data; boundary=b", chunks()))
    ((field, name, spooled),) = files
    assert (field, name, form.fields) == ("file", "C:\\runs\\a b.mp4", {"every_nth": "3"})
    assert spooled.read() == video  # type: ignore[attr-defined]
    assert spooled._rolled  # type: ignore[attr-defined]  # on disk, not in memory
    form.close()
    assert spooled.closed  # type: ignore[attr-defined]
    with pytest.raises(InvalidInputError, match="at most 1; send one video per request"):
        two = body[:-7] + _part("file", b"x", "b.mp4") + b"--b--\r\n"
        asyncio.run(
            StreamedForm(
                lambda *file: None,
                max_files=1,
                max_fields=4,
                spool=2**18,
                limit_hint="; send one video per request",
            ).read("multipart/form-data; boundary=b", _once(two))
        )


async def _once(data: bytes) -> AsyncIterator[bytes]:
    yield data
