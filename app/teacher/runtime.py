"""The teacher's models in this process: loaded once, on first use (through the one loader,
``weldpool_core.teacher.loader``), and shared by the worker's teacher jobs and the web process's
click endpoint (one SAM2, one embedding cache).

The ML stack (torch, transformers) is imported on the first model asked for, not with this
module: a web process that never runs the teacher never loads it.
"""

from __future__ import annotations

import threading
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING

from app.core.config import Settings
from weldpool_core.teacher.prompt_names import DEFAULT_PROMPTS, PromptName

if TYPE_CHECKING:
    from app.storage import Storage
    from weldpool_core.teacher.cache import EmbeddingCache
    from weldpool_core.teacher.dino import DinoAttention
    from weldpool_core.teacher.propagate import Sam2Propagator
    from weldpool_core.teacher.sam2 import Sam2Predictor
    from weldpool_core.teacher.teacher import Teacher

_lock = threading.Lock()


@lru_cache(maxsize=4)
def _sam2(ref: str, device: str) -> Sam2Predictor:
    from weldpool_core.teacher.loader import load_sam2

    return load_sam2(ref, device)


@lru_cache(maxsize=2)
def _sam2_video(ref: str, device: str) -> Sam2Propagator:
    from weldpool_core.teacher.loader import load_sam2_video

    # The video model borrows the image model's vision encoder: one copy of SAM2's largest part.
    return load_sam2_video(ref, device, image_model=_sam2(ref, device))


@lru_cache(maxsize=4)
def _dino(ref: str, device: str, input_size: int) -> DinoAttention:
    from weldpool_core.teacher.loader import load_dino

    return load_dino(ref, device, input_size)


@lru_cache(maxsize=4)
def _cache(directory: Path, limit_bytes: int, shared: SharedEmbeddings | None) -> EmbeddingCache:
    from weldpool_core.teacher.cache import EmbeddingCache

    return EmbeddingCache(directory, disk_limit_bytes=limit_bytes, shared=shared)


EMBEDDINGS_AREA = "embeddings"
"""Where embeddings are shared in an object store (``embeddings/<ab>/<key>.safetensors``)."""


class SharedEmbeddings:
    """The embedding cache's shared tier on an object store: an embedding a worker computed
    is what another machine's first click reads (a fetch of ~8 MB, not an encoder pass)."""

    def __init__(self, storage: Storage) -> None:
        self.storage = storage

    def push(self, name: str, path: Path) -> None:
        self.storage.share(f"{EMBEDDINGS_AREA}/{name}", path)

    def pull(self, name: str, path: Path) -> bool:
        return self.storage.pull(f"{EMBEDDINGS_AREA}/{name}", path)

    def prune(self, older_than_days: float) -> int:
        """Remove shared embeddings not written for ``older_than_days``: the shared tier is a
        cache, bounded by age (a frame's is written again when it is encoded again)."""
        return self.storage.prune_published(EMBEDDINGS_AREA, older_than_days * 86_400)


_shared_tiers: dict[str, SharedEmbeddings] = {}


def shared_embeddings(settings: Settings) -> SharedEmbeddings | None:
    """The shared tier of this instance's object store; None on home alone (its machines
    share the disk cache already)."""
    if not settings.storage_url:
        return None
    with _lock:
        if settings.storage_url not in _shared_tiers:
            from app.storage import open_storage

            # A person's short bounds: a click never waits on a store that hangs (a miss).
            store = open_storage(settings, for_requests=True)
            _shared_tiers[settings.storage_url] = SharedEmbeddings(store)
        return _shared_tiers[settings.storage_url]


def embedding_cache_limit(settings: Settings) -> int:
    """The disk part's size limit in bytes (``WELDPOOL_EMBEDDING_CACHE_MB``)."""
    return int(settings.embedding_cache_mb * 2**20)


def _embedding_dir(settings: Settings) -> Path:
    from app.storage import LocalStorage

    return LocalStorage(settings.home).local("cache/embeddings")  # each machine's own


def embedding_cache_usage(settings: Settings) -> tuple[int, int]:
    """(files, bytes) of the embeddings on disk, read without loading the ML stack."""
    sizes = [p.stat().st_size for p in _embedding_dir(settings).glob("*/*.safetensors")]
    return len(sizes), sum(sizes)


def clear_embedding_cache(settings: Settings) -> tuple[int, int]:
    """Forget every cached embedding: this process's memory (when its cache is loaded) and the
    files on disk; the (files, bytes) removed. Loads no ML library that is not loaded yet."""
    if _cache.cache_info().currsize:
        return embedding_cache(settings).clear()
    files = removed = 0
    for path in _embedding_dir(settings).glob("*/*.safetensors"):
        try:
            size = path.stat().st_size
            path.unlink()
        except FileNotFoundError:
            continue
        files, removed = files + 1, removed + size
    return files, removed


def embedding_cache(settings: Settings) -> EmbeddingCache:
    """The process's embedding cache (memory + WELDPOOL_HOME/cache/embeddings, and the object
    store's ``embeddings/`` shared by every machine when there is one)."""
    return _cache(
        _embedding_dir(settings), embedding_cache_limit(settings), shared_embeddings(settings)
    )


def sam2_predictor(settings: Settings) -> Sam2Predictor:
    """SAM2 as WELDPOOL_SAM2 names it (raises WeightsUnavailableError when missing)."""
    with _lock:
        return _sam2(settings.sam2, settings.device)


def propagator(settings: Settings) -> Sam2Propagator:
    """SAM2's video model from WELDPOOL_SAM2's weights (raises WeightsUnavailableError)."""
    with _lock:
        return _sam2_video(settings.sam2, settings.device)


def teacher(settings: Settings, prompts: PromptName = DEFAULT_PROMPTS) -> Teacher:
    """The teacher as the settings name it, sharing this process's SAM2 and cache."""
    from weldpool_core.teacher.teacher import Teacher, TeacherConfig

    with _lock:
        dino = _dino(settings.dino, settings.device, settings.dino_input_size)
        sam2 = _sam2(settings.sam2, settings.device)
    return Teacher(
        dino,
        sam2,
        settings.sam2,
        embedding_cache(settings),
        TeacherConfig(prompts=prompts),
        settings.dino,
    )


GPU_BATCH = 8
"""Frames per batch of a teacher run on a GPU by default (a chunk holds fewer)."""


def teacher_batch(settings: Settings, teacher: Teacher) -> int:
    """How many frames a teacher run puts through DINO and SAM2's encoder at once: the
    setting, else a chunk's frames on a GPU and one at a time elsewhere (on the CPU a batch
    costs what its frames do one by one)."""
    if settings.teacher_batch:
        return settings.teacher_batch
    return GPU_BATCH if teacher.sam2.device.type == "cuda" else 1
