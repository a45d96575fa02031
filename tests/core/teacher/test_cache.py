"""The embedding cache: memory LRU, fp16 on disk, size limit; a cached embedding gives the
same mask as a fresh one."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.models import tiny_sam2
from weldpool_core.teacher.cache import EmbeddingCache, embedding_key
from weldpool_core.teacher.sam2 import Prompts, upsample_logits

FRAME = np.random.default_rng(5).integers(0, 256, (96, 128, 3), dtype=np.uint8)
CLICKS = [
    Prompts(((64.0, 48.0),), (1,)),
    Prompts(((20.0, 20.0), (100.0, 70.0)), (1, 0)),
    Prompts(box=(10.0, 10.0, 110.0, 80.0)),
]


@pytest.fixture(scope="module")
def predictor():
    return tiny_sam2(seed=1)


def test_embedding_from_disk_gives_the_same_mask(predictor, tmp_path: Path) -> None:
    fresh = predictor.set_image(FRAME)
    writer = EmbeddingCache(tmp_path)
    key = embedding_key("abc123", "sam2-test")
    writer.put(key, fresh)
    reader = EmbeddingCache(tmp_path)  # a new process: nothing in memory
    cached = reader.get(key)
    assert cached is not None and reader.hits["disk"] == 1
    assert cached.image_size == fresh.image_size
    for prompts in CLICKS:
        a = predictor.predict(fresh, prompts)
        b = predictor.predict(cached, prompts)
        np.testing.assert_allclose(a.low_res_logits, b.low_res_logits, atol=2e-2)
        # fp16 storage moves logits by far less than 0.02: only pixels whose logit is that
        # close to the threshold may change side (random weights put many near 0).
        logits = upsample_logits(a.low_res_logits[0], fresh.image_size)
        changed = a.mask != b.mask
        assert np.all(np.abs(logits[changed]) < 2e-2)
        assert changed.mean() < 0.01
        np.testing.assert_allclose(a.scores, b.scores, atol=2e-3)
    assert reader.get(key) is cached and reader.hits["memory"] == 1


def test_memory_lru_and_disk_limit(predictor, tmp_path: Path) -> None:
    embedding = predictor.set_image(FRAME)
    cache = EmbeddingCache(tmp_path, memory_items=2)
    for name in ("a", "b", "c"):
        cache.put(name * 8, embedding)
    assert list(cache._memory) == ["b" * 8, "c" * 8]
    size = next(tmp_path.glob("*/*.safetensors")).stat().st_size
    limited = EmbeddingCache(tmp_path, memory_items=0, disk_limit_bytes=int(size * 2.5))
    limited.put("d" * 8, embedding)
    assert len(list(tmp_path.glob("*/*.safetensors"))) == 2
    assert limited.get("d" * 8) is not None  # the newest stays


def test_damaged_file_is_a_miss(predictor, tmp_path: Path) -> None:
    cache = EmbeddingCache(tmp_path, memory_items=0)
    cache.put("k" * 8, predictor.set_image(FRAME))
    next(tmp_path.glob("*/*.safetensors")).write_bytes(b"garbage")
    assert cache.get("k" * 8) is None
    assert cache.hits["miss"] == 1 and not list(tmp_path.glob("*/*.safetensors"))


def test_keys_depend_on_frame_and_model() -> None:
    assert embedding_key("a", "m1") != embedding_key("a", "m2") != embedding_key("b", "m1")
    assert embedding_key("a", "m1") == embedding_key("a", "m1")
