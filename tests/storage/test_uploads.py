"""Ingest's PUT goes through obstore (``Bucket.create``): the object carries the claim boto3's
reads see, a key already there is not overwritten, and every answer of the store arrives as the
botocore error the service's rules read (a 503 for a request, a pause for a job)."""

from __future__ import annotations

import datetime as dt
import http.server
import ipaddress
import ssl
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import boto3
import pytest
from botocore.exceptions import ClientError, EndpointConnectionError

from app.core.config import StoreWaits
from app.core.errors import failure_sentence, store_outage
from app.storage.s3 import parse_url
from app.storage.s3.bucket import Bucket, _bucket_region, reason, uploads_for
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
def answering(status: int, code: str, tls: ssl.SSLContext | None = None) -> Iterator[str]:
    """An HTTP server on 127.0.0.1 (HTTPS with ``tls``) that answers every PUT with ``status``
    and an S3 error document naming ``code`` (none for a 200); yields its address."""
    document = (
        f'<?xml version="1.0" encoding="UTF-8"?><Error><Code>{code}</Code>'
        "<Message>as the test says</Message></Error>"
    ).encode()
    document = document if status >= 300 else b""

    class Answer(http.server.BaseHTTPRequestHandler):
        def do_PUT(self) -> None:
            self.rfile.read(int(self.headers.get("Content-Length", 0)))
            self.send_response(status)
            self.send_header("Content-Type", "application/xml")
            self.send_header("ETag", '"0"')
            self.send_header("Content-Length", str(len(document)))
            self.end_headers()
            self.wfile.write(document)

        def log_message(self, *args: object) -> None:
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Answer)
    if tls is not None:
        server.socket = tls.wrap_socket(server.socket, server_side=True)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"{'https' if tls else 'http'}://127.0.0.1:{server.server_address[1]}"
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


def test_a_bucket_in_another_region_is_found_when_none_is_set(s3_endpoint: str) -> None:
    """boto3 follows AWS's redirect to a bucket's region; obstore is told it (one HEAD)."""
    name = f"far-{time.time_ns()}"
    boto3.client("s3", endpoint_url=s3_endpoint).create_bucket(
        Bucket=name, CreateBucketConfiguration={"LocationConstraint": "eu-west-1"}
    )
    assert _bucket_region(name, s3_endpoint, WAITS) == "eu-west-1"


def _authority(folder: Path) -> tuple[Path, ssl.SSLContext]:
    """A private CA (its PEM file) and a server context whose certificate it signed for
    127.0.0.1, as a lab's MinIO behind its own CA would be."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    def name(text: str) -> x509.Name:
        return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, text)])

    now = dt.datetime.now(dt.UTC)
    since, until = now - dt.timedelta(hours=1), now + dt.timedelta(hours=1)
    ca_key, key = ec.generate_private_key(ec.SECP256R1()), ec.generate_private_key(ec.SECP256R1())
    ca = (
        x509.CertificateBuilder(
            name("lab CA"), name("lab CA"), ca_key.public_key(), 1, since, until
        )
        .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
        .sign(ca_key, hashes.SHA256())
    )
    server = (
        x509.CertificateBuilder(name("lab CA"), name("store"), key.public_key(), 2, since, until)
        .add_extension(
            x509.SubjectAlternativeName([x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]),
            critical=False,
        )
        .sign(ca_key, hashes.SHA256())
    )
    pem = serialization.Encoding.PEM
    (folder / "ca.pem").write_bytes(ca.public_bytes(pem))
    (folder / "server.pem").write_bytes(
        server.public_bytes(pem)
        + key.private_bytes(pem, serialization.PrivateFormat.PKCS8, serialization.NoEncryption())
    )
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    context.load_cert_chain(folder / "server.pem")
    return folder / "ca.pem", context


def test_a_store_behind_a_private_ca_is_trusted_through_aws_ca_bundle(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    authority, context = _authority(tmp_path)
    with answering(200, "", tls=context) as endpoint:
        with pytest.raises(EndpointConnectionError):  # an unknown CA: no answer taken
            Bucket("s3://lab/f", endpoint, "us-east-1", WAITS).create(b"x", "a.png")
        monkeypatch.setenv("AWS_CA_BUNDLE", str(authority))
        uploads_for.cache_clear()
        assert Bucket("s3://lab/f", endpoint, "us-east-1", WAITS).create(b"x", "b.png")
    uploads_for.cache_clear()
