"""The one place that picks the torch device and precision."""

from __future__ import annotations

from typing import TYPE_CHECKING

from weldpool_core.errors import InvalidInputError

if TYPE_CHECKING:
    import torch


def resolve_device(spec: str = "auto") -> torch.device:
    """The device for ``spec``: ``cpu``, ``cuda``, ``cuda:N``, ``mps`` or ``auto`` (best present).

    Raises InvalidInputError when the asked-for device is not present on this machine.
    """
    import torch

    spec = spec.strip().lower()
    if spec == "auto":
        if torch.cuda.is_available():
            return torch.device("cuda")
        if torch.backends.mps.is_available():
            return torch.device("mps")
        return torch.device("cpu")
    try:
        device = torch.device(spec)
    except RuntimeError as exc:
        raise InvalidInputError(
            f"WELDPOOL_DEVICE={spec!r} is not a device; use cpu, cuda, cuda:N, mps or auto."
        ) from exc
    if device.type == "cuda" and (
        not torch.cuda.is_available()
        or (device.index is not None and device.index >= torch.cuda.device_count())
    ):
        raise InvalidInputError(
            f"WELDPOOL_DEVICE={spec!r} but no such CUDA device is present; use cpu or auto."
        )
    if device.type == "mps" and not torch.backends.mps.is_available():
        raise InvalidInputError(f"WELDPOOL_DEVICE={spec!r} but MPS is not available; use cpu.")
    if device.type not in ("cpu", "cuda", "mps"):
        raise InvalidInputError(
            f"WELDPOOL_DEVICE={spec!r} is not supported; use cpu, cuda, cuda:N, mps or auto."
        )
    return device


def inference_dtype(device: torch.device) -> torch.dtype:
    """Half precision on CUDA (bf16 where supported, else fp16), fp32 elsewhere."""
    import torch

    if device.type == "cuda":
        return torch.bfloat16 if torch.cuda.is_bf16_supported() else torch.float16
    return torch.float32
