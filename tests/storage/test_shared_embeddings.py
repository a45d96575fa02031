"""Embeddings travel: with an object store, an embedding one machine (a worker) computed is
what another machine's (the web process's) first click reads — a fetch, not an encoder pass —
and a store that cannot be read is a miss, never a failed click."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from app.core.config import StoreWaits
from app.storage.s3 import ObjectStorage
from app.teacher.runtime import EMBEDDINGS_AREA, SharedEmbeddings
from tests.models import tiny_sam2
from tests.s3 import bucket_keys
from weldpool_core.teacher.cache import EmbeddingCache, cached_embedding


def _machine(tmp_path: Path, name: str, url: str, endpoint: str) -> EmbeddingCache:
    waits = StoreWaits(connect_s=3.0, read_s=60.0, attempts=5)
    store = ObjectStorage(tmp_path / name, url, 60.0, endpoint, waits=waits)
    return EmbeddingCache(tmp_path / name / "cache", shared=SharedEmbeddings(store))


def test_a_workers_embedding_is_the_web_processs_first_click(
    tmp_path: Path, s3_url: str, s3_endpoint: str
) -> None:
    predictor = tiny_sam2()
    frame = np.random.default_rng(0).integers(0, 256, (48, 64, 3), dtype=np.uint8)
    worker = _machine(tmp_path, "worker", s3_url, s3_endpoint)
    web = _machine(tmp_path, "web", s3_url, s3_endpoint)
    made, tier = cached_embedding(predictor, worker, "ab" * 32, lambda: frame)
    assert tier == "computed"
    shared = bucket_keys(s3_endpoint, s3_url, f"{EMBEDDINGS_AREA}/")
    assert len(shared) == 1 and next(iter(shared.values())) > 0

    def no_encoder() -> np.ndarray:
        raise AssertionError("the web process ran the encoder on a frame a worker embedded")

    read, tier = cached_embedding(predictor, web, "ab" * 32, no_encoder)
    assert tier == "shared" and web.hits["shared"] == 1
    for ours, theirs in zip(read.features, made.features, strict=True):
        torch.testing.assert_close(ours, theirs, atol=2e-3, rtol=2e-3)  # fp16 on the way
    _, tier = cached_embedding(predictor, web, "ab" * 32, no_encoder)
    assert tier == "memory"
    _, tier = cached_embedding(predictor, web, "cd" * 32, lambda: frame)
    assert tier == "computed"  # a frame nobody embedded is encoded


def test_a_store_that_cannot_be_read_is_a_miss(tmp_path: Path, s3_endpoint: str) -> None:
    predictor = tiny_sam2()
    frame = np.zeros((48, 64, 3), np.uint8)
    gone = _machine(tmp_path, "web", "s3://no-such-bucket-here/lab", s3_endpoint)
    _, tier = cached_embedding(predictor, gone, "ef" * 32, lambda: frame)
    assert tier == "computed"  # the pull failed and the push failed: both logged, no error
