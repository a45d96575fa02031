"""The one place that resolves teacher weights: a local directory or a Hugging Face hub id.

A local directory holds a model as ``save_pretrained`` writes it (``config.json`` + weights).
A hub id is looked up in the local hub cache; ``fetch_weights`` downloads it when online.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

WEIGHT_FILES = (
    "model.safetensors",
    "model.safetensors.index.json",
    "pytorch_model.bin",
    "pytorch_model.bin.index.json",
)
DOWNLOAD_PATTERNS = ["*.json", "*.safetensors", "*.txt"]


@dataclass(frozen=True)
class WeightsStatus:
    """Where a model's weights are, and whether they can be loaded without a download."""

    ref: str
    setting: str
    source: str  # "local" or "hub"
    available: bool
    path: str | None
    detail: str

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def public(self) -> dict[str, Any]:
        """As an answer that anyone may read (``/health``) says it: the weights by name
        (``weights_name``), never this machine's path."""
        name = weights_name(self.ref)
        detail = self.detail
        for where in {self.ref, self.path or self.ref, str(Path(self.ref).expanduser())}:
            detail = detail.replace(where, name)
        return {
            "ref": name,
            "setting": self.setting,
            "source": self.source,
            "available": self.available,
            "detail": detail,
        }


def _looks_local(ref: str) -> bool:
    return ref.startswith(("/", ".", "~")) or Path(ref).expanduser().exists()


def weights_name(ref: str) -> str:
    """How recorded results name a model's weights: a hub id as it is, a local directory by its
    folder's name (never the machine's path: workers keeping the same weights under other
    paths name them alike, and users never read a server's paths)."""
    if not _looks_local(ref):
        return ref
    return Path(os.path.abspath(Path(ref).expanduser())).name or ref


def weights_identity(ref: str, path: Path) -> str:
    """Names a model's weights by their content, alike on every machine that holds them: a hub
    id with its revision (the snapshot's commit), else a hash of the folder's config and
    weights (``weights_fingerprint``; its name and path play no part). Recorded results (a
    teacher's ``model_id``) and cached embeddings are keyed by it, so a retried run on another
    worker finds what the first one made, and other weights under the same name never do."""
    if not _looks_local(ref):
        if path.parent.name == "snapshots":
            return f"{ref}@{path.name[:12]}"
        return f"{ref}#{weights_fingerprint(path)}"
    return f"weights#{weights_fingerprint(path)}"


def _weights_in(directory: Path) -> bool:
    return (directory / "config.json").is_file() and any(
        (directory / name).is_file() for name in WEIGHT_FILES
    )


def cached_snapshot(ref: str, cache_dir: str | Path | None = None) -> Path | None:
    """The hub cache's folder of ``ref``'s ``main`` revision, or None where it has none.

    The cache's documented layout (``models--org--name/refs/main`` names the snapshot), read
    as ``huggingface_hub.try_to_load_from_cache`` reads it (a test holds the two equal) but
    without importing the hub's download machinery (~0.1 s): ``/health`` asks on every call,
    the first one while a web process starts.
    """
    from huggingface_hub import constants

    repo = Path(cache_dir or constants.HF_HUB_CACHE) / ("models--" + ref.replace("/", "--"))
    try:
        revision = (repo / "refs" / "main").read_text().strip()
    except OSError:
        revision = "main"
    snapshot = repo / "snapshots" / revision
    return snapshot if (snapshot / "config.json").is_file() else None


def weights_status(ref: str, setting: str) -> WeightsStatus:
    """Whether the model ``ref`` (the value of the variable ``setting``) is ready to load."""
    if _looks_local(ref):
        directory = Path(ref).expanduser()
        if _weights_in(directory):
            return WeightsStatus(ref, setting, "local", True, str(directory), "ready")
        return WeightsStatus(
            ref,
            setting,
            "local",
            False,
            str(directory),
            f"{directory} holds no config.json with model weights; set {setting} to a "
            "directory written by save_pretrained or to a Hugging Face model id.",
        )
    snapshot = cached_snapshot(ref)
    if snapshot is not None and _weights_in(snapshot):
        return WeightsStatus(ref, setting, "hub", True, str(snapshot), "ready (hub cache)")
    return WeightsStatus(
        ref,
        setting,
        "hub",
        False,
        None,
        f"The weights of {ref} are not downloaded; run `weldpool weights fetch` on a machine "
        f"with internet access, or set {setting} to a local directory.",
    )


def fetch_weights(ref: str, setting: str) -> WeightsStatus:
    """Download ``ref`` into the hub cache (a local directory is only checked)."""
    from weldpool_core.errors import WeightsUnavailableError

    if not _looks_local(ref):
        from huggingface_hub import snapshot_download

        try:
            snapshot_download(ref, allow_patterns=DOWNLOAD_PATTERNS)
        except Exception as exc:
            raise WeightsUnavailableError(
                f"Could not download {ref} ({type(exc).__name__}); check the network, or set "
                f"{setting} to a local directory with the model."
            ) from exc
    status = weights_status(ref, setting)
    if not status.available:
        raise WeightsUnavailableError(status.detail)
    return status


def resolve_weights(ref: str, setting: str) -> Path:
    """The local directory that holds ``ref``'s weights, or a WeightsUnavailableError."""
    from weldpool_core.errors import WeightsUnavailableError

    status = weights_status(ref, setting)
    if not status.available or status.path is None:
        raise WeightsUnavailableError(status.detail)
    return Path(status.path)


_FINGERPRINTS: dict[tuple[str, tuple[tuple[str, int, int], ...]], str] = {}


def weights_fingerprint(directory: Path) -> str:
    """A short hash of the model files in ``directory`` (config and weights, by content).

    Cache keys of derived data (SAM2 image embeddings) include it, so re-filling a weights
    folder with other weights never serves results of the old ones. Hashed once per process
    for each (name, size, mtime) listing of the folder.
    """
    import hashlib

    files = sorted(
        p
        for p in directory.iterdir()
        if p.is_file() and p.suffix in (".json", ".safetensors", ".bin")
    )
    listing = tuple((p.name, p.stat().st_size, p.stat().st_mtime_ns) for p in files)
    key = (str(directory.resolve()), listing)
    if key not in _FINGERPRINTS:
        digest = hashlib.sha256()
        for path in files:
            digest.update(path.name.encode() + b"\0")
            with open(path, "rb") as handle:
                while chunk := handle.read(2**20):
                    digest.update(chunk)
        _FINGERPRINTS[key] = digest.hexdigest()[:16]
    return _FINGERPRINTS[key]
