"""Ingest's PUT goes through obstore (``Bucket.create``): the object carries the claim boto3's
reads see, a key already there is not overwritten, and every answer of the store arrives as the
botocore error the service's rules read (a 503 for a request, a pause for a job)."""

from __future__ import annotations

import http.server
import threading
from collections.abc import Iterator
from contextlib import contextmanager

import boto3
import pytest
from botocore.exceptions import ClientError, EndpointConnectionError

from app.core.config import StoreWaits
from app.core.errors import failure_sentence, store_outage
from app.storage.s3 import parse_url
from app.storage.s3.bucket import Bucket, reason
from tests.web.server import free_port

WAITS = StoreWaits(connect_s=2.0, read_s=5.0, attempts=1)


def test_a_put_object_carries_its_claim_and_is_never_overwritten(
    s3_url: str, s3_endpoint: str
) -> None:
    bucket = Bucket(s3_url, s3_endpoint, "us-east-1", WAITS)
    claimed = bucket.create(b"first", "frames/ab/abc.png")
    assert claimed is not None
    # the exact nanoseconds, as the collector's grace reads them (not LastModified's seconds)
    assert bucket.claim_ns("frames/ab/abc.png") == claimed
    assert bucket.create(b"second", "frames/ab/abc.png") is None  # If-None-Match: *
    name, prefix = parse_url(s3_url)
    body = boto3.client("s3", endpoint_url=s3_endpoint).get_object(
        Bucket=name, Key=f"{prefix}/frames/ab/abc.png"
    )["Body"]
    assert body.read() == b"first"


@contextmanager
def answering(status: int, code: str) -> Iterator[str]:
    """An HTTP server on 127.0.0.1 that answers every request with ``status`` and an S3 error
    document naming ``code``; yields its address."""
    document = (
        f'<?xml version="1.0" encoding="UTF-8"?><Error><Code>{code}</Code>'
        "<Message>as the test says</Message></Error>"
    ).encode()

    class Answer(http.server.BaseHTTPRequestHandler):
        def do_PUT(self) -> None:
            self.rfile.read(int(self.headers.get("Content-Length", 0)))
            self.send_response(status)
            self.send_header("Content-Type", "application/xml")
            self.send_header("Content-Length", str(len(document)))
            self.end_headers()
            self.wfile.write(document)

        def log_message(self, *args: object) -> None:
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Answer)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()


@pytest.mark.parametrize(
    ("status", "code", "outage"),
    [(503, "SlowDown", True), (500, "InternalError", True), (403, "AccessDenied", False)],
)
def test_the_stores_answer_is_the_botocore_error_the_rules_read(
    status: int, code: str, outage: bool
) -> None:
    with answering(status, code) as endpoint, pytest.raises(ClientError) as raised:
        Bucket("s3://lab/frames", endpoint, "us-east-1", WAITS).create(b"x", "frames/a.png")
    error = raised.value
    assert error.response["Error"]["Code"] == code
    assert error.response["ResponseMetadata"]["HTTPStatusCode"] == status
    assert store_outage(error) is outage  # a job pauses for an outage, fails for a refusal
    assert code in failure_sentence(error) and code in reason(error, WAITS)
    assert "127.0.0.1" not in reason(error, WAITS)


@pytest.mark.parametrize(
    ("status", "code"), [(412, "PreconditionFailed"), (409, "ConditionalRequestConflict")]
)
def test_a_key_another_writer_holds_or_is_writing_is_not_an_error(status: int, code: str) -> None:
    """412: the object is there; 409: another conditional PUT of it is under way. Either way
    the caller claims the other writer's object instead (``_create_or_claim``)."""
    with answering(status, code) as endpoint:
        assert Bucket("s3://lab/f", endpoint, "us-east-1", WAITS).create(b"x", "a.png") is None


def test_a_store_that_does_not_answer_is_a_connection_error() -> None:
    nobody = f"http://127.0.0.1:{free_port()}"
    with pytest.raises(EndpointConnectionError) as raised:
        Bucket("s3://lab/frames", nobody, "us-east-1", WAITS).create(b"x", "frames/a.png")
    assert store_outage(raised.value)
    assert reason(raised.value, WAITS) == "nothing answers at its address"
