"""The sequential student's network: the gated cell on the latent, the student around it, and the
whole of it as one graph for ONNX."""

from __future__ import annotations

from typing import Any, cast

import torch
from torch import nn

from weldpool_core.student.model import ResNetVAE

UPDATE_BIAS = 4.0
"""The update gate's starting bias: σ(4) ≈ 0.98, so an untrained cell passes the frame through."""


class LatentCell(nn.Module):
    """The gated recurrent cell on the latent mean (see the module doc)."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.channels = channels
        self.gates = nn.Conv2d(3 * channels, 2 * channels, 3, padding=1)
        self.correction = nn.Conv2d(channels, channels, 3, padding=1, bias=False)
        with torch.no_grad():
            self.gates.weight.mul_(0.1)
            bias = torch.zeros(2 * channels)
            bias[:channels] = UPDATE_BIAS
            cast(torch.Tensor, self.gates.bias).copy_(bias)
            self.correction.weight.zero_()

    def forward(self, latent: torch.Tensor, state: torch.Tensor | None) -> torch.Tensor:
        """The new state (= the latent to decode) from this frame's latent and the last state."""
        if state is None:
            return latent
        change = latent - state
        update, reset = torch.sigmoid(self.gates(torch.cat([latent, state, change], 1))).chunk(2, 1)
        candidate = latent + self.correction(reset * change)
        new_state: torch.Tensor = state + update * (candidate - state)
        return new_state


class SequentialStudent(nn.Module):
    """A trained student with a ``LatentCell`` between its encoder and decoder."""

    def __init__(self, student: ResNetVAE, cell: LatentCell) -> None:
        super().__init__()
        self.student = student
        self.cell = cell

    @property
    def config(self) -> Any:
        """The per-frame student's ``StudentConfig``."""
        return self.student.config

    def step(
        self, images: torch.Tensor, state: torch.Tensor | None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Mask logits, heatmap logits (N×S×S) and the new state for one frame per stream."""
        latent, _, skips = self.student.encode(images)
        new_state = self.cell(latent, state)
        mask_logits, heatmap_logits = self.student.decode(new_state, skips)
        return mask_logits, heatmap_logits, new_state


class SequentialExport(nn.Module):
    """The sequential student as ONNX Runtime runs it: probabilities, and a state input that
    ``fresh`` = 1 replaces by the frame's own latent (the first frame of a stream)."""

    def __init__(self, model: SequentialStudent) -> None:
        super().__init__()
        self.model = model

    def forward(
        self, image: torch.Tensor, state: torch.Tensor, fresh: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        latent, _, skips = self.model.student.encode(image)
        start = fresh * latent + (1 - fresh) * state
        new_state = self.model.cell(latent, start)
        mask_logits, heatmap_logits = self.model.student.decode(new_state, skips)
        return torch.sigmoid(mask_logits), torch.sigmoid(heatmap_logits), new_state
