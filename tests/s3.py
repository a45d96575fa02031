"""The S3-protocol server the suite runs against: moto's standalone server on 127.0.0.1.

`.ci/run` starts it and sets WELDPOOL_TEST_S3_ENDPOINT; the suite then fails, not skips, when it
does not answer. Without that variable (a developer's machine) the first test that needs it
starts one from this virtual environment on a free port, for the whole session."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

os.environ.setdefault("AWS_ACCESS_KEY_ID", "weldpool-test")
os.environ.setdefault("AWS_SECRET_ACCESS_KEY", "weldpool-test")
os.environ.setdefault("AWS_REGION", "us-east-1")
ENDPOINT_VARIABLE = "WELDPOOL_TEST_S3_ENDPOINT"


def _answers(endpoint: str) -> bool:
    import httpx

    try:
        httpx.get(endpoint, timeout=2.0)
    except httpx.HTTPError:
        return False
    return True


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@pytest.fixture(scope="session")
def s3_endpoint(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """The endpoint of a real S3-protocol server (fails when CI's does not answer)."""
    given = os.environ.get(ENDPOINT_VARIABLE)
    if given:
        if not _answers(given):
            pytest.fail(
                f"The S3 server at {given} ({ENDPOINT_VARIABLE}) does not answer; start it "
                "(`.venv/bin/moto_server -H 127.0.0.1 -p 5000`). The suite must run against a "
                "real S3-protocol server.",
                pytrace=False,
            )
        yield given
        return
    server = Path(sys.executable).with_name("moto_server")
    if not server.exists() and shutil.which("moto_server") is None:
        pytest.fail("moto_server is missing: pip install -e '.[test]'.", pytrace=False)
    port = _free_port()
    log = open(tmp_path_factory.mktemp("moto") / "moto.log", "w")  # noqa: SIM115
    process = subprocess.Popen(
        [str(server) if server.exists() else "moto_server", "-H", "127.0.0.1", "-p", str(port)],
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    endpoint = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 30
    while not _answers(endpoint):
        if time.monotonic() > deadline or process.poll() is not None:
            process.kill()
            pytest.fail(f"moto_server did not start on {endpoint}.", pytrace=False)
        time.sleep(0.1)
    yield endpoint
    process.terminate()
    process.wait(timeout=10)
    log.close()


def make_bucket(endpoint: str) -> str:
    """A new empty bucket; its name."""
    import boto3

    name = f"wp-{uuid.uuid4().hex[:16]}"
    boto3.client("s3", endpoint_url=endpoint).create_bucket(Bucket=name)
    return name


@pytest.fixture
def s3_url(s3_endpoint: str) -> str:
    """``s3://<a fresh bucket>/lab`` on the suite's S3 server."""
    return f"s3://{make_bucket(s3_endpoint)}/lab"


def bucket_keys(endpoint: str, url: str, prefix: str = "") -> dict[str, int]:
    """Every key under ``prefix`` in the bucket of ``url`` (relative to the store): its size."""
    import boto3

    from app.storage.s3 import parse_url

    bucket, root = parse_url(url)
    client = boto3.client("s3", endpoint_url=endpoint)
    found: dict[str, int] = {}
    for page in client.get_paginator("list_objects_v2").paginate(
        Bucket=bucket, Prefix=f"{root}/{prefix}"
    ):
        for item in page.get("Contents", []):
            found[item["Key"].removeprefix(f"{root}/")] = int(item["Size"])
    return found
