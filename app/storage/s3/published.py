"""Shared files that are not content-addressed, in the bucket by name: model folders (published
whole or file by file), export zips, uploaded imports, shared embeddings. Each uploaded file's
modification time becomes its object's, so a machine knows its copy current."""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Iterable
from pathlib import Path

from app.core.budgets import shared_pool
from app.storage.s3.cache import ObjectCache

POOL = shared_pool(8, "storage-publish")  # publishing, and reading ahead


class Published:
    """Folders and files published under their relative paths."""

    def __init__(self, cache: ObjectCache) -> None:
        self.cache = cache
        self.bucket = cache.bucket
        self.home = cache.files.home

    def folder(self, relative: str) -> Path | None:
        """A published folder, made complete on this machine: files it lacks, or holds older
        than the bucket's (a job replaced them), are fetched. Files only this machine has stay
        (an ONNX export a live view made from the weights)."""
        path = self.cache.files.local(relative)
        objects = {
            self.bucket.relative_of(o["Key"]): o for o in self.bucket.objects(f"{relative}/")
        }
        if not objects:
            return path if path.is_dir() else None
        for name, item in objects.items():
            local = self.home / name
            stamp = item["LastModified"].timestamp()
            try:
                info = local.stat()
                current = info.st_size == item["Size"] and info.st_mtime >= stamp
            except FileNotFoundError:
                current = False
            if not current and self.cache.fetch(name, local):
                os.utime(local, (stamp, stamp))
        return path

    def publish(self, relative: str, names: Iterable[str] | None = None) -> None:
        """Upload a file, or a folder's files, under their relative paths; returns once every
        upload is complete. A folder is made to match this machine's copy (keys it lacks are
        withdrawn) — unless ``names`` are given: then only those files of it are uploaded, or
        withdrawn where this copy has none (another job may be changing the folder's others)."""
        path = self.cache.files.local(relative)
        now = time.time_ns()
        if path.is_file():
            self.bucket.upload_file(path, relative, now)
            return
        if not path.is_dir():
            raise FileNotFoundError(f"{relative} is not on this machine; nothing to publish.")
        if names is None:
            files = {p.relative_to(self.home).as_posix(): p for p in path.rglob("*") if p.is_file()}
            gone = [
                o["Key"]
                for o in self.bucket.objects(f"{relative}/")
                if self.bucket.relative_of(o["Key"]) not in files
            ]
        else:
            chosen = {f"{relative}/{name}": path / name for name in names}
            files = {key: local for key, local in chosen.items() if local.is_file()}
            gone = [self.bucket.key(key) for key in chosen if key not in files]
        list(POOL.map(lambda i: self.bucket.upload_file(i[1], i[0], now), files.items()))
        self.bucket.delete_keys(gone)
        for item in self.bucket.objects(f"{relative}/"):  # local times := the bucket's
            local = files.get(self.bucket.relative_of(item["Key"]))
            if local is not None:
                stamp = item["LastModified"].timestamp()
                with contextlib.suppress(FileNotFoundError):
                    os.utime(local, (stamp, stamp))

    def unpublish(self, relative: str) -> None:
        """Withdraw a published file or folder."""
        keys = [o["Key"] for o in self.bucket.objects(f"{relative}/")]
        self.bucket.delete_keys([*keys, self.bucket.key(relative)])

    def prune(self, area: str, older_than_s: float) -> int:
        """Delete the objects of ``area`` older than ``older_than_s``; returns how many."""
        cutoff = time.time() - older_than_s
        old = [
            o["Key"]
            for o in self.bucket.objects(f"{area}/")
            if o["LastModified"].timestamp() < cutoff
        ]
        self.bucket.delete_keys(old)
        return len(old)

    def push(self, remote: str) -> tuple[int, int]:
        """Upload every shared file of home the bucket lacks (an instance that kept its files
        in home, moving to the store); returns (uploaded, already there). Home is then
        ``remote``'s cache."""
        from app.storage.protocol import SHARED_AREAS

        present = {
            self.bucket.relative_of(o["Key"])
            for a in SHARED_AREAS
            for o in self.bucket.objects(f"{a}/")
        }
        local = self.cache.own_files()
        missing = [r for r in local if r not in present and not r.startswith("models/.work")]
        now = time.time_ns()
        list(POOL.map(lambda r: self.bucket.upload_file(self.home / r, r, now), missing))
        self.cache.mark(remote)
        return len(missing), len(local) - len(missing)
