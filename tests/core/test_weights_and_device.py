"""weldpool_core's one place for weights and the one place for the device."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from weldpool_core.device import inference_dtype, resolve_device
from weldpool_core.errors import InvalidInputError, WeightsUnavailableError
from weldpool_core.teacher.weights import fetch_weights, weights_status


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
