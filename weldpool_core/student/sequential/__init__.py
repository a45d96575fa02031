"""The sequential student: a recurrent cell on a trained student's latent (the paper's future
work: "a sequential student that keeps temporal information").

A per-frame student sees each frame alone, so glare flicker, floating oxide and sensor noise move
its mask and keypoints from frame to frame even where the pool stands still. The sequential
student keeps the per-frame student as it is (encoder and decoder frozen) and adds one small
gated cell between them, on the stride-32 latent mean ``x_t`` (C×h×w):

    d = x_t − s_{t−1}                         (the innovation: what this frame says that is new)
    z, r = σ(conv₃ₓ₃[x_t, s_{t−1}, d])        (per latent cell and channel)
    c = x_t + conv₃ₓ₃(r ⊙ d)                  (the frame's latent, corrected by what changed)
    s_t = s_{t−1} + z ⊙ (c − s_{t−1})         (the state, decoded as the frame's latent)

With no state (the first frame of a stream, or after a reset) ``s = x_t``, so ``d = 0`` and
``s_t = x_t``: the first frame is the per-frame student's answer exactly. The cell starts close
to the identity (z ≈ 0.98, the correction conv zero), so an untrained cell changes little; training
teaches it how much of the past to keep, cell by cell, from the size and kind of the innovation:
a small flicker is averaged away, a real move of the pool is followed at once. It is causal (no
future frame) and costs two 3×3 convolutions at stride 32: well under 1 % of the student.

Training (``train_sequential``) needs no labels on consecutive frames, only videos in which some
frames are labelled: each example is a window of ``window`` consecutive video frames ending at a
labelled frame (frame stride drawn from ``strides``, so the cell does not learn one frame rate).
The pool barely moves within a window of a fraction of a second (the camera moves with the
torch), so every step of the window is supervised with the labelled frame's targets — moved by
the window's synthetic motion: each window gets one shared random affine (as the per-frame
student's augmentation) plus a constant drift of up to ``drift`` of the input side per frame, and
the targets of step t are shifted by the drift at t. A cell that only averaged would trail that
drift and pay for it in the loss; one that ignored the past would pay for each frame's own
photometric noise (drawn independently per step, as real glare and noise are). The loss is the
per-frame student's (BCE + Dice on the mask, focal on the heatmap), on the decoded state of the
second half of each window (the steps with a past). A steadiness term adds unlabelled windows of
the same videos (``unlabelled_windows`` per video, evenly spaced, with the same drift and
noise): ``unsteadiness``, the share of the mask that changes from one step to the next beyond
the known drift. Measured on the real videos (``bench/sequential.py``), this term is what makes
the cell steady the held-out clip: supervision alone took 7–10 % off the keypoint jitter.

A MODEL_DIR with a trained cell holds ``sequential.safetensors`` and ``sequential.json`` (its
settings and training record); ``sequential.onnx`` is the whole sequential student for ONNX
Runtime (inputs ``image`` and ``state`` and ``fresh``; outputs mask, heatmap and the new state).

The package: ``model`` (the cell and the student around it), ``config`` (its settings), ``data``
(clips and windows), ``training`` (``train_sequential``), ``measure`` (``measure_sequential``),
``checkpoint`` (its files in MODEL_DIR) and ``export`` (the ONNX file); the names below are
the package's API.
"""

from __future__ import annotations

from weldpool_core.student.sequential.checkpoint import (
    SEQUENTIAL_CONFIG,
    SEQUENTIAL_ONNX,
    SEQUENTIAL_WEIGHTS,
    has_sequential,
    load_sequential,
    save_cell,
)
from weldpool_core.student.sequential.config import SequentialConfig
from weldpool_core.student.sequential.data import (
    FRAME_STEM,
    VIDEO_SUFFIXES,
    LabelledClip,
    dataset_clips,
    needed_frames,
    unlabelled_ends,
    video_clip,
)
from weldpool_core.student.sequential.export import export_sequential_onnx
from weldpool_core.student.sequential.measure import measure_sequential
from weldpool_core.student.sequential.model import (
    UPDATE_BIAS,
    LatentCell,
    SequentialExport,
    SequentialStudent,
)
from weldpool_core.student.sequential.training import (
    SequentialResult,
    Window,
    clip_windows,
    encode_windows,
    shift,
    train_sequential,
    unroll,
    unsteadiness,
)

__all__ = [
    "FRAME_STEM",
    "SEQUENTIAL_CONFIG",
    "SEQUENTIAL_ONNX",
    "SEQUENTIAL_WEIGHTS",
    "UPDATE_BIAS",
    "VIDEO_SUFFIXES",
    "LabelledClip",
    "LatentCell",
    "SequentialConfig",
    "SequentialExport",
    "SequentialResult",
    "SequentialStudent",
    "Window",
    "clip_windows",
    "dataset_clips",
    "encode_windows",
    "export_sequential_onnx",
    "has_sequential",
    "load_sequential",
    "measure_sequential",
    "needed_frames",
    "save_cell",
    "shift",
    "train_sequential",
    "unlabelled_ends",
    "unroll",
    "unsteadiness",
    "video_clip",
]
