"""weldpool_core's one place for weights and the one place for the device."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from weldpool_core.device import inference_dtype, resolve_device
from weldpool_core.errors import InvalidInputError, WeightsUnavailableError
from weldpool_core.teacher.weights import (
    fetch_weights,
    weights_identity,
    weights_name,
    weights_status,
)


def test_local_directory_with_weights_is_ready(tmp_path: Path) -> None:
    (tmp_path / "config.json").write_text("{}")
    assert not weights_status(str(tmp_path), "WELDPOOL_DINO").available
    (tmp_path / "model.safetensors").write_bytes(b"")
    status = weights_status(str(tmp_path), "WELDPOOL_DINO")
    assert status.available and status.source == "local" and status.path == str(tmp_path)


def test_missing_local_directory_names_the_variable(tmp_path: Path) -> None:
    status = weights_status(str(tmp_path / "nope"), "WELDPOOL_SAM2")
    assert not status.available
    assert "set WELDPOOL_SAM2" in status.detail


def test_hub_id_offline_is_a_clear_error(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    status = weights_status("facebook/dino-vits8", "WELDPOOL_DINO")
    assert status.source == "hub"
    with pytest.raises(WeightsUnavailableError, match="WELDPOOL_DINO"):
        fetch_weights("facebook/dino-vits8", "WELDPOOL_DINO")


def test_device_resolution() -> None:
    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device("auto").type in ("cpu", "cuda", "mps")
    assert inference_dtype(torch.device("cpu")) == torch.float32
    with pytest.raises(InvalidInputError, match="WELDPOOL_DEVICE"):
        resolve_device("tpu")
    if not torch.cuda.is_available():
        with pytest.raises(InvalidInputError, match="no such CUDA device"):
            resolve_device("cuda:1")


def test_the_hub_cache_is_read_as_huggingface_hub_reads_it(tmp_path: Path) -> None:
    """`cached_snapshot` (no hub import at start-up) finds what `try_to_load_from_cache`
    finds: nothing for an unknown id or an empty repo folder, the snapshot that refs/main
    names (not another one), and a status that is ready only with weights in it."""
    from huggingface_hub import try_to_load_from_cache

    from weldpool_core.teacher.weights import cached_snapshot

    def hubs(ref: str) -> Path | None:
        found = try_to_load_from_cache(ref, "config.json", cache_dir=tmp_path)
        return Path(found).parent if isinstance(found, str) else None

    ref = "facebook/sam2.1-hiera-tiny"
    repo = tmp_path / "models--facebook--sam2.1-hiera-tiny"
    assert cached_snapshot(ref, tmp_path) is None is hubs(ref)
    (repo / "refs").mkdir(parents=True)
    assert cached_snapshot(ref, tmp_path) is None is hubs(ref)
    for commit in ("a" * 40, "b" * 40):
        (repo / "snapshots" / commit).mkdir(parents=True)
        (repo / "snapshots" / commit / "config.json").write_text("{}")
    (repo / "refs" / "main").write_text("b" * 40)
    assert cached_snapshot(ref, tmp_path) == repo / "snapshots" / ("b" * 40) == hubs(ref)
    assert cached_snapshot("facebook/dino-vits8", tmp_path) is None is hubs("facebook/dino-vits8")


def test_a_hub_snapshot_with_weights_is_ready(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    from huggingface_hub import constants

    monkeypatch.setattr(constants, "HF_HUB_CACHE", str(tmp_path))
    snapshot = tmp_path / "models--facebook--dino-vits8" / "snapshots" / ("c" * 40)
    snapshot.mkdir(parents=True)
    (tmp_path / "models--facebook--dino-vits8" / "refs").mkdir()
    (tmp_path / "models--facebook--dino-vits8" / "refs" / "main").write_text("c" * 40)
    (snapshot / "config.json").write_text("{}")
    assert not weights_status("facebook/dino-vits8", "WELDPOOL_DINO").available
    (snapshot / "model.safetensors").write_bytes(b"")
    status = weights_status("facebook/dino-vits8", "WELDPOOL_DINO")
    assert status.available and status.source == "hub" and status.path == str(snapshot)


def test_weights_are_named_by_hub_id_or_folder_never_by_path(tmp_path: Path) -> None:
    """What results record (a teacher's model_id): the same on workers whose folders differ."""
    for home in ("one", "two"):
        (tmp_path / home / "weights" / "sam2").mkdir(parents=True)
        assert weights_name(str(tmp_path / home / "weights" / "sam2") + "/") == "sam2"
    assert weights_name("facebook/sam2.1-hiera-tiny") == "facebook/sam2.1-hiera-tiny"


def test_weights_are_identified_by_content_or_hub_revision(tmp_path: Path) -> None:
    """The identity results are keyed by: equal for equal files under any folder name, other
    for other bytes under the same name, a hub id with its snapshot's commit; never a path."""
    for folder, weights in (("a/sam2", b"123"), ("b/copy", b"123"), ("c/sam2", b"124")):
        (tmp_path / folder).mkdir(parents=True)
        (tmp_path / folder / "config.json").write_text("{}")
        (tmp_path / folder / "model.safetensors").write_bytes(weights)
    a, b, c = (
        weights_identity(str(tmp_path / f), tmp_path / f) for f in ("a/sam2", "b/copy", "c/sam2")
    )
    assert a == b and a != c
    assert str(tmp_path) not in a and "sam2" not in a
    snapshot = tmp_path / "models--facebook--sam2" / "snapshots" / ("d" * 40)
    assert weights_identity("facebook/sam2", snapshot) == "facebook/sam2@" + "d" * 12
