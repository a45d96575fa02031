"""The embedding cache: SAM2 image embeddings by frame hash and model, in memory and on disk.

Memory holds the last few embeddings (LRU, in the model's precision) for interactive clicks;
disk holds many more in fp16 (about 8 MB a frame) as safetensors files, the least recently
used ones removed beyond a size limit; a disk hit comes back in the precision the caller's
model runs in (bf16 on a GPU). A click on a frame the teacher has seen never re-encodes it.

``cached_embedding`` is the one seam every user goes through (teacher runs, clicks): it keys
by the frame's hash and the predictor's ``cache_identity`` (weights hash, precision,
pre-processing version) and says which tier served.
"""

from __future__ import annotations

import hashlib
import logging
import os
import threading
import uuid
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Literal, Protocol

import numpy as np
import torch
from numpy.typing import NDArray
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from weldpool_core.teacher.sam2 import ImageEmbedding

log = logging.getLogger(__name__)

if TYPE_CHECKING:
    from weldpool_core.teacher.sam2 import Sam2Predictor

_NAMES = ("s0", "s1", "image")
Tier = Literal["memory", "disk", "shared", "computed"]
"""Where an embedding came from: the memory LRU, the disk cache, the shared store (another
machine computed it), or the image encoder."""


class SharedTier(Protocol):
    """A store every machine of an instance reaches (an object store): each embedding file
    written here is shared, and one this machine lacks is looked for there before the encoder
    runs. ``name`` is the file's path relative to the cache's directory."""

    def push(self, name: str, path: Path) -> None: ...

    def pull(self, name: str, path: Path) -> bool: ...


def embedding_key(image_sha256: str, identity: str) -> str:
    """The cache key of one frame's embedding under one model identity
    (``Sam2Predictor.cache_identity``: weights, precision, pre-processing)."""
    return hashlib.sha256(f"{identity}\n{image_sha256}".encode()).hexdigest()[:40]


class EmbeddingCache:
    """A two-level cache of ``ImageEmbedding`` objects (thread-safe).

    Args:
        directory: where fp16 copies live; None keeps the cache in memory only.
        memory_items: embeddings kept in memory (each about 17 MB in fp32).
        disk_limit_bytes: the disk part's size limit; oldest-used files go first.
        shared: a tier shared with other machines (workers), below the disk: a file written
            is pushed there, and a disk miss is pulled from it before it counts as a miss.
    """

    def __init__(
        self,
        directory: Path | None = None,
        memory_items: int = 8,
        disk_limit_bytes: int = 20 * 2**30,
        shared: SharedTier | None = None,
    ) -> None:
        self.directory = directory
        self.shared = shared
        self.memory_items = memory_items
        self.disk_limit_bytes = disk_limit_bytes
        self._memory: OrderedDict[str, ImageEmbedding] = OrderedDict()
        self._lock = threading.Lock()
        self._computing: dict[str, threading.Lock] = {}
        self.hits = {"memory": 0, "disk": 0, "shared": 0, "miss": 0}
        if directory is not None:
            directory.mkdir(parents=True, exist_ok=True)

    def _path(self, key: str) -> Path:
        assert self.directory is not None
        return self.directory / key[:2] / f"{key}.safetensors"

    def in_memory(self, key: str) -> bool:
        """Whether ``key`` is held in memory now (a fetch would not read or compute it)."""
        with self._lock:
            return key in self._memory

    def get(
        self, key: str, device: torch.device | None = None, dtype: torch.dtype | None = None
    ) -> ImageEmbedding | None:
        """The embedding under ``key`` (on ``device``, in ``dtype``; default fp32), or None."""
        found = self._lookup(key, device, dtype)
        return found[0] if found else None

    def _lookup(
        self, key: str, device: torch.device | None, dtype: torch.dtype | None
    ) -> tuple[ImageEmbedding, Tier] | None:
        with self._lock:
            if key in self._memory:
                self._memory.move_to_end(key)
                self.hits["memory"] += 1
                return self._memory[key], "memory"
        tier: Tier = "disk"
        missing = self.directory is not None and not self._path(key).exists()
        if missing and self.shared is not None and self._pull(key, self._path(key)):
            tier = "shared"
        if self.directory is not None and (path := self._path(key)).exists():
            try:
                tensors = load_file(str(path), device=str(device or "cpu"))
            except (OSError, ValueError, RuntimeError, SafetensorError):
                path.unlink(missing_ok=True)  # a damaged file is a miss
            else:
                os.utime(path)  # mark as recently used for the size limit
                size = tuple(int(v) for v in tensors.pop("image_size").tolist())
                features = tuple(tensors[name].to(dtype or torch.float32) for name in _NAMES)
                embedding = ImageEmbedding(features, (size[0], size[1]))  # type: ignore[arg-type]
                self._remember(key, embedding)
                with self._lock:
                    self.hits[tier] += 1
                return embedding, tier
        with self._lock:
            self.hits["miss"] += 1
        return None

    def fetch(
        self,
        key: str,
        compute: Callable[[], ImageEmbedding],
        *,
        device: torch.device | None = None,
        dtype: torch.dtype | None = None,
        image_size: tuple[int, int] | None = None,
    ) -> tuple[ImageEmbedding, Tier]:
        """The embedding under ``key`` and the tier that served it; computed and stored on a
        miss. Concurrent fetches of one key compute it once (the others wait, then hit
        memory). An entry of another ``image_size`` is treated as a miss."""
        with self._lock:
            key_lock = self._computing.setdefault(key, threading.Lock())
        with key_lock:
            found = self._lookup(key, device, dtype)
            if found is not None and (image_size is None or found[0].image_size == image_size):
                return found
            embedding = compute()
            self.put(key, embedding)
        with self._lock:
            self._computing.pop(key, None)
        return embedding, "computed"

    def put(self, key: str, embedding: ImageEmbedding) -> None:
        """Keep ``embedding`` in memory and (if a directory is set) on disk in fp16."""
        self._remember(key, embedding)
        if self.directory is None:
            return
        path = self._path(key)
        path.parent.mkdir(parents=True, exist_ok=True)
        tensors = {
            name: t.detach().to("cpu", torch.float16).contiguous()
            for name, t in zip(_NAMES, embedding.features, strict=True)
        }
        tensors["image_size"] = torch.tensor(embedding.image_size, dtype=torch.int64)
        temporary = path.with_name(f".{uuid.uuid4().hex}.part")
        save_file(tensors, str(temporary))
        os.replace(temporary, path)
        self._enforce_limit()
        if self.shared is not None:
            try:
                self.shared.push(self._name(key), path)
            except Exception:  # the shared copy is an optimisation: a click computes without it
                log.warning("sharing embedding %s failed", key, exc_info=True)

    def _name(self, key: str) -> str:
        return f"{key[:2]}/{key}.safetensors"

    def _pull(self, key: str, path: Path) -> bool:
        assert self.shared is not None
        try:
            return self.shared.pull(self._name(key), path)
        except Exception:  # an unreachable store is a miss, never a failed click
            log.warning("reading shared embedding %s failed", key, exc_info=True)
            return False

    def _remember(self, key: str, embedding: ImageEmbedding) -> None:
        with self._lock:
            self._memory[key] = embedding
            self._memory.move_to_end(key)
            while len(self._memory) > self.memory_items:
                self._memory.popitem(last=False)

    def usage(self) -> tuple[int, int]:
        """(files, bytes) the disk part holds now."""
        if self.directory is None:
            return 0, 0
        sizes = [p.stat().st_size for p in self.directory.glob("*/*.safetensors")]
        return len(sizes), sum(sizes)

    def clear(self) -> tuple[int, int]:
        """Forget every embedding, in memory and on disk; the (files, bytes) removed. The next
        click on each frame computes its embedding again."""
        with self._lock:
            self._memory.clear()
        if self.directory is None:
            return 0, 0
        files = removed = 0
        for path in self.directory.glob("*/*.safetensors"):
            try:
                size = path.stat().st_size
                path.unlink()
            except FileNotFoundError:  # another process removed it meanwhile
                continue
            files, removed = files + 1, removed + size
        return files, removed

    def _enforce_limit(self) -> None:
        assert self.directory is not None
        files = [
            (p.stat().st_mtime, p.stat().st_size, p) for p in self.directory.glob("*/*.safetensors")
        ]
        total = sum(size for _, size, _ in files)
        for _, size, path in sorted(files):
            if total <= self.disk_limit_bytes:
                break
            path.unlink(missing_ok=True)
            total -= size


def cached_embedding(
    predictor: Sam2Predictor,
    cache: EmbeddingCache | None,
    image_sha256: str | None,
    image: Callable[[], NDArray[np.uint8]],
    image_size: tuple[int, int] | None = None,
) -> tuple[ImageEmbedding, Tier]:
    """SAM2's embedding of a frame through the cache: the one seam for teacher runs and clicks.

    ``image`` is called only on a miss (a click on a cached frame never reads the file). The
    key is the frame's hash under ``predictor.cache_identity``; a hit comes back on the
    predictor's device and in its precision.
    """
    if cache is None or image_sha256 is None:
        return predictor.set_image(image()), "computed"
    return cache.fetch(
        embedding_key(image_sha256, predictor.cache_identity),
        lambda: predictor.set_image(image()),
        device=predictor.device,
        dtype=predictor.dtype,
        image_size=image_size,
    )
