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
from botocore.exceptions import ClientError, EndpointConnectionError, ReadTimeoutError

from app.core.config import StoreWaits
from app.core.errors import ConfigurationError, failure_sentence, store_outage
from app.storage.s3 import parse_url, uploads
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
def answering(
    status: int, code: str, tls: ssl.SSLContext | None = None, puts: list[int] | None = None
) -> Iterator[str]:
    """An HTTP server on 127.0.0.1 (HTTPS with ``tls``) that answers a bucket's HEAD naming its
    region, and every PUT with ``status`` and an S3 error document naming ``code`` (none for a
    200), or never (status 0); ``puts`` counts the PUTs. Yields its address."""
    document = (
        f'<?xml version="1.0" encoding="UTF-8"?><Error><Code>{code}</Code>'
        "<Message>as the test says</Message></Error>"
    ).encode()
    document = document if status >= 300 else b""
    closing = threading.Event()

    class Answer(http.server.BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"

        def do_HEAD(self) -> None:
            self.send_response(200)
            self.send_header("x-amz-bucket-region", "eu-north-1")
            self.send_header("Content-Length", "0")
            self.end_headers()

        def do_PUT(self) -> None:
            self.rfile.read(int(self.headers.get("Content-Length", 0)))
            if puts is not None:
                puts.append(1)
            if "x-amz-copy-source" in self.headers:  # a claim: the key is not there (yet)
                missing = b"<Error><Code>NoSuchKey</Code><Message>none</Message></Error>"
                self.send_response(404)
                self.send_header("Content-Length", str(len(missing)))
                self.end_headers()
                self.wfile.write(missing)
                return
            if status == 0:
                closing.wait(30)
                return
            self.send_response(status)
            self.send_header("Content-Type", "application/xml")
            self.send_header("ETag", '"0"')
            self.send_header("Content-Length", str(len(document)))
            self.end_headers()
            self.wfile.write(document)

        def log_message(self, *args: object) -> None:
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Answer)
    server.daemon_threads = True
    if tls is not None:
        server.socket = tls.wrap_socket(server.socket, server_side=True)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"{'https' if tls else 'http'}://127.0.0.1:{server.server_address[1]}"
    finally:
        closing.set()
        server.shutdown()
        server.server_close()


@pytest.mark.parametrize(
    ("status", "code", "outage"),
    [
        (503, "SlowDown", True),
        (500, "InternalError", True),
        (403, "AccessDenied", False),
        (301, "PermanentRedirect", False),  # another region's endpoint: obstore does not follow
    ],
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


def test_another_conflict_is_the_stores_error_not_a_key_that_is_there() -> None:
    with answering(409, "OperationAborted") as endpoint, pytest.raises(ClientError) as raised:
        Bucket("s3://lab/f", endpoint, "us-east-1", WAITS).create(b"x", "a.png")
    assert raised.value.response["Error"]["Code"] == "OperationAborted"


def test_a_store_that_never_answers_a_put_is_tried_as_often_as_the_waits_say() -> None:
    """A timeout is retried (obstore retries none for a PUT) and reads as one."""
    waits = StoreWaits(connect_s=1.0, read_s=0.5, attempts=3)
    puts: list[int] = []
    with answering(0, "", puts=puts) as endpoint, pytest.raises(ReadTimeoutError) as raised:
        Bucket("s3://lab/f", endpoint, "us-east-1", waits).create(b"x", "a.png")
    assert len(puts) == 3
    assert store_outage(raised.value)
    assert reason(raised.value, waits) == "it did not answer within 4.5 s"


def test_a_503_is_tried_again_and_a_403_is_not() -> None:
    waits = StoreWaits(connect_s=1.0, read_s=2.0, attempts=2)
    for status, code, tries in ((503, "SlowDown", 2), (403, "AccessDenied", 1), (501, "", 1)):
        puts: list[int] = []
        with answering(status, code, puts=puts) as endpoint, pytest.raises(ClientError):
            Bucket("s3://lab/f", endpoint, "us-east-1", waits).create(b"x", "a.png")
        assert len(puts) == tries, code


def test_a_store_that_does_not_answer_is_a_connection_error() -> None:
    nobody = f"http://127.0.0.1:{free_port()}"
    with pytest.raises(EndpointConnectionError) as raised:
        Bucket("s3://lab/frames", nobody, "us-east-1", WAITS).create(b"x", "frames/a.png")
    assert store_outage(raised.value)
    assert reason(raised.value, WAITS) == "nothing answers at its address"


def test_the_buckets_own_region_wins_over_the_configured_one(s3_endpoint: str) -> None:
    """boto3 follows AWS's redirect to a bucket's region; obstore is told it (one HEAD)."""
    name = f"far-{time.time_ns()}"
    client = boto3.client("s3", endpoint_url=s3_endpoint)
    client.create_bucket(Bucket=name, CreateBucketConfiguration={"LocationConstraint": "eu-west-1"})
    assert uploads.bucket_region(client, name) == "eu-west-1"


def test_a_head_naming_no_region_leaves_the_clients_and_a_failing_one_guesses_none() -> None:
    """A store that names no region (some S3 servers): the client's own, as boto3 signs with;
    a HEAD that fails for the moment (503) fails the making of the client, kept by nobody."""
    from botocore.stub import Stubber

    from app.storage.s3.bucket import client_for

    client = client_for("http://127.0.0.1:9", "eu-west-1", WAITS)
    with Stubber(client) as stub:
        stub.add_response("head_bucket", {})
        assert uploads.bucket_region(client, "lab") == "eu-west-1"
        stub.add_client_error("head_bucket", "SlowDown", http_status_code=503)
        with pytest.raises(ClientError):
            uploads.bucket_region(client, "lab")


def test_on_aws_the_put_goes_to_the_buckets_host_in_its_region() -> None:
    """No endpoint of its own: AWS, addressed by host (by path for a dotted name), in the
    region the bucket's HEAD names (stubbed: nothing here reaches AWS)."""
    from botocore.stub import Stubber

    from app.storage.s3.bucket import client_for

    for bucket, hosted in (("weldpool-lab", True), ("weld.pool", False)):
        client = client_for(None, "us-west-2", WAITS)
        with Stubber(client) as stub:
            headers = {"x-amz-bucket-region": "eu-central-1"}
            stub.add_response("head_bucket", {"ResponseMetadata": {"HTTPHeaders": headers}})
            store, _ = uploads.uploads_for(bucket, client, WAITS)
        config = store.config
        assert "endpoint" not in config and config["region"] == "eu-central-1"
        assert config.get("virtual_hosted_style_request") == str(hosted).lower(), bucket
    private = "https://bucket.vpce-1a2b.s3.us-east-1.vpce.amazonaws.com"  # PrivateLink: as is
    client = client_for(private, "us-east-1", WAITS)
    with Stubber(client) as stub:
        stub.add_response("head_bucket", {})
        config = uploads.uploads_for("weldpool-lab", client, WAITS)[0].config
    assert config["endpoint"] == private and config["virtual_hosted_style_request"] == "false"


def test_refreshable_credentials_are_read_again_well_before_they_expire() -> None:
    from botocore.credentials import Credentials as Static
    from botocore.credentials import RefreshableCredentials

    later = dt.datetime.now(dt.UTC) + dt.timedelta(minutes=20)
    refreshable = RefreshableCredentials("a", "b", "t", later, lambda: {}, "test")
    answer = uploads.Credentials(refreshable)()
    assert answer["token"] == "t"
    assert answer["expires_at"] <= dt.datetime.now(dt.UTC) + dt.timedelta(minutes=5)
    assert uploads.Credentials(Static("a", "b"))()["expires_at"] is None  # never expire


def test_credentials_that_cannot_be_had_are_boto3s_error(
    s3_url: str, s3_endpoint: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An expired SSO token: the error boto3 would have raised, not the store's refusal."""
    from botocore.exceptions import TokenRetrievalError

    class Expired:
        def get_frozen_credentials(self) -> None:
            raise TokenRetrievalError(provider="sso", error_msg="the token expired")

    bucket = Bucket(s3_url, s3_endpoint, "us-east-1", WAITS)
    store, _ = uploads.uploads_for(bucket.name, bucket.client, WAITS)
    failing = uploads.Credentials(Expired())
    made = type(store)(
        bucket.name,
        endpoint=s3_endpoint,
        region="us-east-1",
        credential_provider=failing,
        client_options={"allow_http": True},
        retry_config={"max_retries": 0},
    )
    monkeypatch.setattr(uploads, "uploads_for", lambda *args: (made, failing))
    with pytest.raises(TokenRetrievalError):
        bucket.create(b"x", "frames/a.png")


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
    from botocore.exceptions import SSLError

    from app.storage.s3.bucket import client_for

    authority, context = _authority(tmp_path)
    with answering(200, "", tls=context) as endpoint:
        with pytest.raises(SSLError):  # an unknown CA: boto3 refuses it, as ever
            Bucket("s3://lab/f", endpoint, "us-east-1", WAITS).create(b"x", "a.png")
        monkeypatch.setenv("AWS_CA_BUNDLE", str(authority))
        client_for.cache_clear()  # clients are made once a process, as the settings are read
        uploads.uploads_for.cache_clear()
        assert Bucket("s3://lab/f", endpoint, "us-east-1", WAITS).create(b"x", "b.png")
        monkeypatch.setenv("AWS_CA_BUNDLE", str(tmp_path / "gone.pem"))
        uploads.uploads_for.cache_clear()
        with pytest.raises(ConfigurationError, match="CA bundle"):
            Bucket("s3://lab/f", endpoint, "us-east-1", WAITS).create(b"x", "c.png")
    client_for.cache_clear()
    uploads.uploads_for.cache_clear()


def test_a_key_another_writer_keeps_writing_is_an_outage_not_a_500(tmp_path: Path) -> None:
    """409 to every PUT and no object to claim: tried a few times with pauses, then the store's
    conflict, which a request answers with a 503 and a job waits out."""
    from app.storage.s3 import ObjectStorage

    puts: list[int] = []
    with answering(409, "ConditionalRequestConflict", puts=puts) as endpoint:
        store = ObjectStorage(tmp_path, "s3://lab/f", 60.0, endpoint, waits=WAITS)
        started = time.monotonic()
        with pytest.raises(ClientError) as raised:
            store.put(b"x" * 10, "ab" * 32, ".png")
    assert raised.value.response["Error"]["Code"] == "ConditionalRequestConflict"
    assert store_outage(raised.value)
    assert len(puts) == 16  # eight conditional PUTs, each followed by a claim that found none
    assert time.monotonic() - started >= 2.0  # with pauses between them, not a busy loop
