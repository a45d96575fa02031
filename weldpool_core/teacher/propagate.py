"""SAM2's video model carrying reviewed masks through a weld run, frame by frame.

A weld pool changes slowly: one corrected mask, given to SAM2's memory, segments the next frames
with memory attention and the mask decoder only. ``Sam2Propagator`` drives transformers'
``Sam2VideoModel`` one frame at a time with our own pre- and post-processing:

- Image features come from the one embedding seam (``cache.cached_embedding`` through the
  image predictor, which shares SAM2's vision encoder weights): frames the teacher has seen
  cost no encoder pass here. The image embedding's features are turned into the video model's
  (flattened, and without the "no memory" embedding the image model adds to the top level).
- No frame pixels are held: the session only knows how many frames the run has.
- The memory bank is bounded: outputs of tracked frames further than SAM2 can look back (its
  memory frames, its object pointers) are dropped as the run goes on, except the few next to
  where a pass started (the other direction's pass reads them), and of the ones kept only what
  later frames read (memory features, object pointer). Memory does not grow with the run.
- Each frame's confidence is SAM2's own: the probability that the object is there (object
  score) times the predicted IoU of the mask it chose.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, cast

import numpy as np
import torch
import torch.nn.functional as F
from numpy.typing import NDArray

from weldpool_core.errors import InvalidInputError
from weldpool_core.teacher.passes import Direction, passes
from weldpool_core.teacher.sam2 import SAM2_INPUT_SIZE, ImageEmbedding, upsample_logits

OBJECT_ID = 1


@dataclass(frozen=True)
class PropagatedMask:
    """The mask SAM2 carried to frame ``index`` from the prompted frame ``source_index``."""

    index: int
    mask: NDArray[np.bool_]
    object_score: float
    """SAM2's probability that the pool is in the frame (sigmoid of its object-score logit)."""
    iou: float
    """SAM2's predicted IoU of the mask it chose."""
    source_index: int
    low_res_logits: NDArray[np.float32]

    @property
    def confidence(self) -> float:
        return self.object_score * self.iou


class _FrameCount(dict):  # type: ignore[type-arg]
    """Stands for the run's frames in a session: transformers reads only how many there are
    (features come from the embedding seam, so no pixels are kept)."""

    def __init__(self, count: int) -> None:
        super().__init__()
        self.count = count

    def __len__(self) -> int:
        return self.count


class Sam2Propagator:
    """Owns a ``Sam2VideoModel``; ``propagate`` carries prompt masks through a run's frames."""

    def __init__(self, model: Any, device: torch.device | None = None) -> None:
        self.device = device or torch.device("cpu")
        self.model: Any = cast(Any, model).to(self.device).eval()
        self.dtype = next(self.model.parameters()).dtype
        config = self.model.config
        self.keep = max(int(config.num_maskmem), int(config.max_object_pointers_in_encoder))
        """Tracked frames SAM2 can look back on: older outputs are dropped."""
        self._ious: list[torch.Tensor] = []
        self.model.mask_decoder.register_forward_hook(self._capture_iou)
        with torch.inference_mode():
            self._positions = [
                self._position_encoding(tuple(size)) for size in self.model.backbone_feature_sizes
            ]

    @classmethod
    def from_config(cls, config: Any, device: torch.device | None = None) -> Sam2Propagator:
        """A SAM2 video model with random weights (tests, benchmarks)."""
        from transformers import Sam2VideoModel

        config._attn_implementation = "sdpa"
        return cls(Sam2VideoModel(config), device)

    def _capture_iou(self, _module: Any, _inputs: Any, outputs: Any) -> None:
        self._ious.append(outputs[1].detach())

    def _position_encoding(self, size: tuple[int, int]) -> torch.Tensor:
        """The vision encoder's sine positional encoding of one feature level, flattened the way
        ``Sam2VideoModel.get_image_features`` gives it (it depends on the size only)."""
        neck = self.model.vision_encoder.neck
        shape = torch.Size((1, int(self.model.config.vision_config.fpn_hidden_size), *size))
        encoding = neck.position_encoding(shape, self.device, self.dtype).to(self.dtype)
        return cast(torch.Tensor, encoding.flatten(2).permute(2, 0, 1))

    def video_features(self, embedding: ImageEmbedding) -> dict[str, list[torch.Tensor]]:
        """The video model's vision features from an image embedding (the teacher's cache)."""
        levels = [
            f.to(self.device, self.dtype).flatten(2).permute(2, 0, 1) for f in embedding.features
        ]
        levels[-1] = levels[-1] - self.model.no_memory_embedding.to(self.dtype)
        return {"vision_feats": levels, "vision_pos_embeds": list(self._positions)}

    def mask_input(self, mask: NDArray[np.bool_]) -> torch.Tensor:
        """A prompt mask at SAM2's input size, as transformers' video processor makes it."""
        tensor = torch.as_tensor(np.asarray(mask, dtype=np.float32))[None, None].to(self.device)
        size = (SAM2_INPUT_SIZE, SAM2_INPUT_SIZE)
        if tuple(tensor.shape[-2:]) != size:
            tensor = F.interpolate(
                tensor, size=size, mode="bilinear", align_corners=False, antialias=True
            )
            tensor = (tensor >= 0.5).float()
        return tensor

    def session(self, count: int, image_size: tuple[int, int]) -> Any:
        """A streaming session for ``count`` frames that holds no pixels."""
        from transformers.models.sam2_video.modeling_sam2_video import Sam2VideoInferenceSession

        session = Sam2VideoInferenceSession(
            video_height=image_size[0],
            video_width=image_size[1],
            inference_device=self.device,
            inference_state_device=self.device,
            video_storage_device=self.device,
            dtype=self.dtype,
            max_vision_features_cache_size=1,
        )
        session.processed_frames = _FrameCount(count)
        session.obj_id_to_idx(OBJECT_ID)
        return session

    @torch.inference_mode()
    def propagate(
        self,
        count: int,
        prompts: dict[int, NDArray[np.bool_]],
        embedding: Callable[[int], ImageEmbedding],
        direction: Direction = "both",
        until: int | None = None,
        keep_going: Callable[[PropagatedMask, bool], bool] | None = None,
    ) -> Iterator[PropagatedMask]:
        """Masks for the frames ``0 … count-1`` of a run from prompt masks on some of them.

        Args:
            count: frames in the run, in frame order.
            prompts: prompt masks (reviewed labels) by frame position.
            embedding: the SAM2 image embedding of a frame position (the teacher's cache).
            direction: forward from the first prompt, backward from it, or both.
            until: the last position to reach (forward) or the first (backward); default the
                run's end or start.
            keep_going: called with each mask and whether its pass runs backward; False ends
                that pass (where confidence has dropped), and the next pass starts.

        Yields:
            One ``PropagatedMask`` per frame without a prompt, in the order they are computed
            (forward pass first). Stop iterating to stop (a cancelled job): nothing is kept.
        """
        if not prompts:
            raise InvalidInputError("Propagation needs at least one reviewed frame to start from.")
        if any(not 0 <= i < count for i in prompts):
            raise InvalidInputError("A frame to propagate from is not in the run.")
        image_size = embedding(next(iter(prompts))).image_size
        session = self.session(count, image_size)
        obj_idx = session.obj_id_to_idx(OBJECT_ID)
        for index in sorted(prompts):
            self._cache(session, index, embedding)
            session.add_mask_inputs(obj_idx, index, self.mask_input(prompts[index]))
            session.obj_with_new_inputs = [OBJECT_ID]
            self.model(session, frame_idx=index)
        first = min(prompts)
        for order, reverse in passes(count, prompts, direction, until):
            start = order.start
            for index in order:
                if index in prompts:
                    continue
                self._cache(session, index, embedding)
                self._ious.clear()
                output = self.model(session, frame_idx=index, reverse=reverse)
                self._forget(session, obj_idx, index, start, reverse)
                low_res = output.pred_masks[0, 0].float()
                iou = float(self._ious[-1].float().max()) if self._ious else float("nan")
                behind = [p for p in prompts if (p > index if reverse else p < index)]
                source = (min(behind) if reverse else max(behind)) if behind else first
                logits = low_res.cpu().numpy()
                item = PropagatedMask(
                    index=index,
                    mask=upsample_logits(logits, image_size) > 0,
                    object_score=float(
                        torch.sigmoid(output.object_score_logits.float().flatten()[0])
                    ),
                    iou=iou,
                    source_index=source,
                    low_res_logits=logits,
                )
                yield item
                if keep_going is not None and not keep_going(item, reverse):
                    break

    def _cache(self, session: Any, index: int, embedding: Callable[[int], ImageEmbedding]) -> None:
        session.cache.cache_vision_features(index, self.video_features(embedding(index)))

    def _forget(self, session: Any, obj_idx: int, index: int, start: int, reverse: bool) -> None:
        """Drop tracked outputs SAM2 can no longer look back on (bounded memory), keeping the
        ones next to where this pass started (the other direction's pass reads them)."""
        tracked = session.output_dict_per_obj[obj_idx]["non_cond_frame_outputs"]
        current = tracked.get(index)
        if current is not None:  # read only in the step that made them (the caller has them)
            current.pop("high_res_masks", None)
            current.pop("pred_masks", None)
        for old in list(tracked):
            far_from_here = abs(old - index) > self.keep
            far_from_start = abs(old - start) > self.keep
            if far_from_here and far_from_start:
                del tracked[old]
