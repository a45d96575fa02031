"""A cell whose gates are set by hand, for the sequential tests."""

from __future__ import annotations

import numpy as np
import torch

from weldpool_core.student.sequential import LatentCell


def gated_cell(channels: int, update: float, correction: float = 0.0) -> LatentCell:
    """A cell whose update gate is ``update`` everywhere, reset gate 1, and whose correction
    adds ``correction`` × the (reset) innovation."""
    cell = LatentCell(channels)
    with torch.no_grad():
        cell.gates.weight.zero_()
        bias = torch.full((2 * channels,), 30.0)  # reset gate σ(30) = 1
        bias[:channels] = float(np.log(update / (1 - update)))
        cell.gates.bias.copy_(bias)
        cell.correction.weight.zero_()
        for channel in range(channels):
            cell.correction.weight[channel, channel, 1, 1] = correction
    return cell
