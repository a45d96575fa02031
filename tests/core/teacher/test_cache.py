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


def _bf16(predictor):  # type: ignore[no-untyped-def]
    import copy

    import torch

    from weldpool_core.teacher.sam2 import Sam2Predictor

    return Sam2Predictor(copy.deepcopy(predictor.model).to(torch.bfloat16), weights_id="tiny")


def test_a_bf16_model_reads_its_embedding_back_from_disk(predictor, tmp_path: Path) -> None:
    """On CUDA the models run in bf16; a disk hit must come back in bf16 (it is stored fp16),
    or the decoder fails with a dtype error (a 500 on a click from another process)."""
    import torch

    from weldpool_core.teacher.cache import cached_embedding

    bf16 = _bf16(predictor)
    fresh, tier = cached_embedding(bf16, EmbeddingCache(tmp_path), "f" * 64, lambda: FRAME)
    assert tier == "computed" and fresh.features[2].dtype == torch.bfloat16
    other_process = EmbeddingCache(tmp_path)
    cached, tier = cached_embedding(bf16, other_process, "f" * 64, lambda: FRAME)
    assert tier == "disk"
    assert all(t.dtype == torch.bfloat16 for t in cached.features)
    for prompts in CLICKS:
        a, b = bf16.predict(fresh, prompts), bf16.predict(cached, prompts)
        np.testing.assert_allclose(a.scores, b.scores, atol=5e-2)
        assert (a.mask != b.mask).mean() < 0.02


def test_the_key_names_weights_precision_and_preprocessing(predictor, tmp_path: Path) -> None:
    """A re-filled weights folder, another precision or a new pre-processing version never
    serves an embedding computed by the old one."""
    import torch

    import weldpool_core.teacher.sam2 as sam2_module
    from tests.models import tiny_sam2
    from weldpool_core.teacher.cache import cached_embedding
    from weldpool_core.teacher.loader import load_sam2

    folder = tmp_path / "weights"
    predictor.model.save_pretrained(folder)
    first = load_sam2(str(folder), "cpu")
    assert first.cache_identity == load_sam2(str(folder), "cpu").cache_identity
    cache = EmbeddingCache(tmp_path / "cache")
    assert cached_embedding(first, cache, "f" * 64, lambda: FRAME)[1] == "computed"
    assert (
        cached_embedding(first, EmbeddingCache(tmp_path / "cache"), "f" * 64, lambda: FRAME)[1]
        == "disk"
    )

    tiny_sam2(seed=7).model.save_pretrained(folder)  # the folder re-filled with other weights
    refilled = load_sam2(str(folder), "cpu")
    assert refilled.cache_identity != first.cache_identity
    fresh_cache = EmbeddingCache(tmp_path / "cache")
    assert cached_embedding(refilled, fresh_cache, "f" * 64, lambda: FRAME)[1] == "computed"

    in_bf16 = _bf16(predictor)
    in_fp32 = sam2_module.Sam2Predictor(predictor.model, weights_id="tiny")
    assert in_bf16.cache_identity != in_fp32.cache_identity
    assert in_bf16.dtype == torch.bfloat16
    before = in_fp32.cache_identity
    sam2_module.PREPROCESSING_VERSION += 1
    try:
        assert in_fp32.cache_identity != before
    finally:
        sam2_module.PREPROCESSING_VERSION -= 1


def test_one_seam_says_which_tier_served_even_under_concurrent_clicks(
    predictor, tmp_path: Path
) -> None:
    import threading

    from weldpool_core.teacher.cache import cached_embedding

    cache = EmbeddingCache(tmp_path)
    encoded = []

    def image():  # type: ignore[no-untyped-def]
        encoded.append(1)
        return FRAME

    tiers: list[str] = []
    barrier = threading.Barrier(4)

    def click() -> None:
        barrier.wait()
        tiers.append(cached_embedding(predictor, cache, "c" * 64, image)[1])

    threads = [threading.Thread(target=click) for _ in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert sorted(tiers) == ["computed", "memory", "memory", "memory"] and len(encoded) == 1
    assert cached_embedding(predictor, EmbeddingCache(tmp_path), "c" * 64, image)[1] == "disk"
    assert cached_embedding(predictor, None, "c" * 64, image)[1] == "computed"
    assert len(encoded) == 2
