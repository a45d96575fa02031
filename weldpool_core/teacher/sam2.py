"""SAM2 with our own pre- and post-processing, and a predictor that owns image embeddings.

``Sam2Processor`` needs torchvision, so the small processing is here: the frame is resized to
1024×1024 (SAM2 resizes without keeping the aspect ratio), normalised with ImageNet statistics;
prompt coordinates are scaled by 1024 / width and 1024 / height; the 256×256 mask logits are
resized bilinearly to the frame and thresholded at 0.

``Sam2Predictor.set_image`` runs the image encoder once (``hiera.image_encoder``: on the CPU
``hiera.ImageEncoder``, transformers' encoder re-stated without its unused work, same numbers;
transformers' own where no interleaved bench measured ours faster); ``predict`` then runs only
the prompt encoder and the mask decoder. The decoder pass is our own re-statement of transformers'
``Sam2MaskDecoder`` (same weights, same numbers; a test checks it against ``Sam2Model``) that
computes what does not depend on the prompt once per image: the image tokens in token-major
layout, their sum with the positional encoding, and the first block's image-side projections.
"""

from __future__ import annotations

import uuid
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np
import torch
import torch.nn.functional as F
from numpy.typing import NDArray
from transformers import Sam2Config, Sam2Model

from weldpool_core.errors import InvalidInputError
from weldpool_core.teacher.dino import IMAGENET_MEAN, IMAGENET_STD
from weldpool_core.teacher.hiera import image_encoder

SAM2_INPUT_SIZE = 1024
PREPROCESSING_VERSION = 1
"""Bump when ``Sam2Predictor.preprocess`` changes: embeddings cached by older code are unused."""


def input_coordinates(points: torch.Tensor, image_size: tuple[int, int]) -> torch.Tensor:
    """Frame pixels ``(..., 2)`` as ``(x, y)`` → SAM2's 1024² input space (the one place).

    SAM2 resizes the frame to 1024×1024 without keeping its aspect ratio, so x scales by
    1024 / width and y by 1024 / height.
    """
    height, width = image_size
    scale = torch.tensor([SAM2_INPUT_SIZE / width, SAM2_INPUT_SIZE / height], dtype=points.dtype)
    return points * scale


@dataclass(frozen=True)
class Prompts:
    """Prompts in full-resolution pixel coordinates of the frame.

    ``points``: (x, y) pairs; ``labels``: 1 positive, 0 negative, one per point; ``box``:
    (x0, y0, x1, y1) or None; ``mask_logits``: a previous 256×256 low-resolution logit map to
    refine, or None.
    """

    points: tuple[tuple[float, float], ...] = ()
    labels: tuple[int, ...] = ()
    box: tuple[float, float, float, float] | None = None
    mask_logits: NDArray[np.float32] | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        if len(self.points) != len(self.labels):
            raise InvalidInputError("Each prompt point needs a label (1 positive, 0 negative).")
        if any(label not in (0, 1) for label in self.labels):
            raise InvalidInputError("Point labels are 1 (positive) or 0 (negative).")
        if self.box is not None and not (self.box[0] < self.box[2] and self.box[1] < self.box[3]):
            raise InvalidInputError("A box is (x0, y0, x1, y1) with x0 < x1 and y0 < y1.")

    @property
    def empty(self) -> bool:
        return not self.points and self.box is None and self.mask_logits is None

    def as_dict(self) -> dict[str, Any]:
        """JSON-friendly form (without the mask logits)."""
        return {
            "points": [[float(x), float(y)] for x, y in self.points],
            "labels": list(self.labels),
            "box": list(self.box) if self.box else None,
        }


@dataclass
class ImageEmbedding:
    """SAM2's encoding of one frame: the three feature levels and the frame's size.

    ``features``: (s0 1×32×256×256, s1 1×64×128×128, image 1×256×64×64), as
    ``Sam2Model.get_image_embeddings`` returns them. ``derived`` holds prompt-independent
    decoder inputs computed on first use (never stored).
    """

    features: tuple[torch.Tensor, torch.Tensor, torch.Tensor]
    image_size: tuple[int, int]
    derived: dict[str, torch.Tensor] = field(default_factory=dict, repr=False)


@dataclass(frozen=True)
class MaskPrediction:
    """Candidate masks for one prompt set, best first by SAM2's predicted IoU.

    Only the low-resolution logits are kept; ``mask`` / ``full_mask(i)`` resize a candidate to
    the frame when asked (most callers need the best one only).
    """

    low_res_logits: NDArray[np.float32]  # n × 256 × 256
    scores: NDArray[np.float32]  # predicted IoU, n
    object_score: float  # SAM2's logit that an object is there at all
    image_size: tuple[int, int]

    def full_mask(self, index: int = 0) -> NDArray[np.bool_]:
        """Candidate ``index`` at the frame's resolution (bilinear, threshold 0)."""
        return upsample_logits(self.low_res_logits[index], self.image_size) > 0

    @property
    def mask(self) -> NDArray[np.bool_]:
        return self.full_mask(0)

    @property
    def score(self) -> float:
        return float(self.scores[0])


def upsample_logits(logits: NDArray[np.float32], size: tuple[int, int]) -> NDArray[np.float32]:
    """Low-resolution mask logits resized to ``size`` (height, width), as SAM2 does."""
    tensor = torch.from_numpy(np.ascontiguousarray(logits, np.float32))[None, None]
    resized = F.interpolate(tensor, size=size, mode="bilinear", align_corners=False)
    out: NDArray[np.float32] = resized[0, 0].numpy()
    return out


class Sam2Predictor:
    """Owns a SAM2 model; ``set_image`` once per frame, then any number of ``predict`` calls.

    Args:
        model: a ``Sam2Model`` (default weights: ``facebook/sam2.1-hiera-tiny``).
        device: where the model runs.
        weights_id: names the weights (the loader passes the reference and a hash of the
            files); unnamed models get a name of their own, so they never share cached
            embeddings with another model.
    """

    def __init__(
        self, model: Sam2Model, device: torch.device | None = None, weights_id: str | None = None
    ) -> None:
        self.identity = weights_id
        """Its weights by content (``weights_identity``), where the loader named them."""
        self.weights_id = weights_id or f"unnamed-{uuid.uuid4().hex}"
        self.device = device or torch.device("cpu")
        self.model: Any = cast(Any, model)
        self.model.to(self.device).eval()
        self.dtype = next(model.parameters()).dtype
        self._mean = torch.tensor(IMAGENET_MEAN, device=self.device).view(1, 3, 1, 1)
        self._std = torch.tensor(IMAGENET_STD, device=self.device).view(1, 3, 1, 1)
        with torch.inference_mode():
            pe = self.model.get_image_wide_positional_embeddings()  # 1 × C × 64 × 64
        self._image_pe = pe.flatten(2).transpose(1, 2).contiguous().to(self.dtype)  # 1×4096×C
        self._encoder = image_encoder(self.model, self.device)

    @classmethod
    def from_config(cls, config: Sam2Config, device: torch.device | None = None) -> Sam2Predictor:
        """A SAM2 with random weights (tests, benchmarks)."""
        config._attn_implementation = "sdpa"
        return cls(Sam2Model(config), device)

    @property
    def cache_identity(self) -> str:
        """What an image embedding depends on besides the frame: weights, precision and
        pre-processing. Cache keys include it."""
        dtype = str(self.dtype).removeprefix("torch.")
        return f"{self.weights_id}|{dtype}|pre{PREPROCESSING_VERSION}@{SAM2_INPUT_SIZE}"

    # --- image ---------------------------------------------------------------------------------

    def preprocess(self, image: NDArray[np.uint8]) -> torch.Tensor:
        """RGB uint8 H×W×3 → normalised 1×3×1024×1024 on the model's device."""
        if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
            raise InvalidInputError("SAM2 takes an RGB uint8 image of shape H×W×3.")
        tensor = torch.from_numpy(image).to(self.device).permute(2, 0, 1)[None].float() / 255.0
        size = (SAM2_INPUT_SIZE, SAM2_INPUT_SIZE)
        tensor = F.interpolate(
            tensor, size=size, mode="bilinear", align_corners=False, antialias=True
        )
        return ((tensor - self._mean) / self._std).to(self.dtype)

    @torch.inference_mode()
    def set_image(self, image: NDArray[np.uint8]) -> ImageEmbedding:
        """Run the image encoder once; the returned embedding serves every later prompt."""
        features = self._encoder(self.preprocess(image))
        s0, s1, top = (f.contiguous() for f in features)
        return ImageEmbedding((s0, s1, top), (int(image.shape[0]), int(image.shape[1])))

    @torch.inference_mode()
    def set_images(self, images: list[NDArray[np.uint8]]) -> list[ImageEmbedding]:
        """The encoder on several frames in one batch (a GPU worker's teacher run): one
        embedding per frame, as ``set_image`` gives it up to the batched kernels' rounding."""
        features = self._encoder(torch.cat([self.preprocess(image) for image in images]))
        return [
            ImageEmbedding(
                tuple(f[index : index + 1].contiguous() for f in features),  # type: ignore[arg-type]
                (int(image.shape[0]), int(image.shape[1])),
            )
            for index, image in enumerate(images)
        ]

    # --- prompts -------------------------------------------------------------------------------

    def _sparse(self, prompts: Prompts, image_size: tuple[int, int]) -> torch.Tensor | None:
        """Points and box scaled to the 1024² input, through SAM2's prompt encoder."""
        points = labels = boxes = None
        if prompts.points:
            xy = torch.tensor(prompts.points, dtype=torch.float32)
            points = input_coordinates(xy, image_size)[None, None]
            labels = torch.tensor(prompts.labels, dtype=torch.int64)[None, None]
        if prompts.box is not None:
            corners = torch.tensor(prompts.box, dtype=torch.float32).view(2, 2)
            boxes = input_coordinates(corners, image_size).view(1, 1, 4)
        if points is None and boxes is None:
            if prompts.mask_logits is None:
                return None
            points = torch.zeros(1, 1, 1, 2)  # SAM2's "no point" padding
            labels = -torch.ones(1, 1, 1, dtype=torch.int64)
        encoder = self.model.prompt_encoder
        sparse: list[torch.Tensor] = []
        if points is not None and labels is not None:
            sparse.append(
                encoder._embed_points(
                    points.to(self.device), labels.to(self.device), pad=boxes is None
                )
            )
        if boxes is not None:
            sparse.append(encoder._embed_boxes(boxes.to(self.device)))
        return torch.cat(sparse, dim=2).to(self.dtype)

    @torch.inference_mode()
    def predict(
        self, embedding: ImageEmbedding, prompts: Prompts, multimask: bool | None = None
    ) -> MaskPrediction:
        """Masks for ``prompts`` from a cached embedding; no image encoder runs here.

        ``multimask`` None follows SAM2: three candidates for a single ambiguous click, one
        (chosen by stability) otherwise.
        """
        if multimask is None:
            multimask = len(prompts.points) <= 1 and prompts.box is None
        sparse = self._sparse(prompts, embedding.image_size)
        if sparse is None:
            raise InvalidInputError("Give at least one point, a box or a previous mask.")
        dense = None
        if prompts.mask_logits is not None:
            logits = torch.as_tensor(prompts.mask_logits, dtype=torch.float32)
            if tuple(logits.shape) != (256, 256):
                raise InvalidInputError("A previous mask must be the 256×256 low-res logits.")
            dense = self.model.prompt_encoder.mask_embed(
                logits[None, None].to(self.device, self.dtype)
            )
        low_res, iou, object_score = decode_masks(
            self.model, embedding, self._image_pe, sparse, dense, multimask
        )
        return self._postprocess(low_res[0], iou[0], float(object_score[0]), embedding.image_size)

    @torch.inference_mode()
    def predict_points(
        self, embedding: ImageEmbedding, points: NDArray[np.float32] | list[tuple[float, float]]
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """One positive click per prompt set, B clicks decoded together (SAM2's automatic mode).

        ``points``: B × 2 ``(x, y)`` in frame pixels. Returns the three multimask candidates:
        low-res logits B × 3 × 256 × 256, predicted IoU B × 3 and object-score logits B, in
        float32. Same coordinate transform and decoder as ``predict``.
        """
        xy = torch.as_tensor(np.asarray(points, np.float32)).view(-1, 2)
        scaled = input_coordinates(xy, embedding.image_size)[None, :, None, :]  # 1 × B × 1 × 2
        labels = torch.ones(scaled.shape[:3], dtype=torch.int64)
        sparse = self.model.prompt_encoder._embed_points(
            scaled.to(self.device), labels.to(self.device), pad=True
        )
        low_res, iou, objects = decode_masks(
            self.model, embedding, self._image_pe, sparse.to(self.dtype), None, True
        )
        return low_res.float(), iou.float(), objects.float()

    def _postprocess(
        self,
        low_res: torch.Tensor,
        iou: torch.Tensor,
        object_score: float,
        image_size: tuple[int, int],
    ) -> MaskPrediction:
        order = torch.argsort(iou.float(), descending=True)
        return MaskPrediction(
            low_res_logits=low_res[order].float().cpu().numpy(),
            scores=iou[order].float().cpu().numpy(),
            object_score=object_score,
            image_size=image_size,
        )


def _attention(
    module: Any,
    query: torch.Tensor,
    key: torch.Tensor,
    value: torch.Tensor,
    projected: tuple[torch.Tensor | None, torch.Tensor | None] = (None, None),
) -> torch.Tensor:
    """``Sam2Attention`` on B × N × C tensors, optionally with keys/values already projected."""
    batch = query.shape[0]
    heads = module.num_attention_heads
    q = module.q_proj(query).view(batch, -1, heads, module.head_dim).transpose(1, 2)
    k = projected[0] if projected[0] is not None else module.k_proj(key)
    v = projected[1] if projected[1] is not None else module.v_proj(value)
    k = k.expand(batch, -1, -1).view(batch, -1, heads, module.head_dim).transpose(1, 2)
    v = v.expand(batch, -1, -1).view(batch, -1, heads, module.head_dim).transpose(1, 2)
    out = F.scaled_dot_product_attention(q, k, v, scale=module.scaling)
    projected_out: torch.Tensor = module.o_proj(
        out.transpose(1, 2).reshape(batch, -1, heads * module.head_dim)
    )
    return projected_out


def _image_side(
    model: Any, embedding: ImageEmbedding, image_pe: torch.Tensor
) -> dict[str, torch.Tensor]:
    """Prompt-independent decoder inputs (for prompts without a mask), computed once."""
    if not embedding.derived:
        decoder = model.mask_decoder
        first = decoder.transformer.layers[0]
        no_mask = model.prompt_encoder.no_mask_embed.weight.view(1, 1, -1)
        keys = embedding.features[2].flatten(2).transpose(1, 2) + no_mask  # 1 × 4096 × C
        keys_pe = keys + image_pe
        embedding.derived.update(
            keys=keys.contiguous(),
            keys_pe=keys_pe,
            k0=first.cross_attn_token_to_image.k_proj(keys_pe),
            v0=first.cross_attn_token_to_image.v_proj(keys),
            q0=first.cross_attn_image_to_token.q_proj(keys_pe),
        )
    return embedding.derived


def _image_keys(
    model: Any, embedding: ImageEmbedding, image_pe: torch.Tensor, dense: torch.Tensor | None
) -> tuple[torch.Tensor, torch.Tensor, tuple[Any, Any], torch.Tensor | None]:
    """The image side of the two-way transformer: keys, keys with PE, and the first block's
    projected keys/values and image queries (from the embedding's cache without a mask
    prompt; None with one, as they depend on it)."""
    if dense is None:
        cached = _image_side(model, embedding, image_pe)
        return cached["keys"], cached["keys_pe"], (cached["k0"], cached["v0"]), cached["q0"]
    keys = (embedding.features[2] + dense).flatten(2).transpose(1, 2).contiguous()
    return keys, keys + image_pe, (None, None), None


def _two_way(
    transformer: Any,
    tokens: torch.Tensor,
    image: tuple[torch.Tensor, torch.Tensor, tuple[Any, Any], torch.Tensor | None],
    image_pe: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """SAM2's two-way transformer over the prompt tokens (B × T' × C) and the image keys:
    the queries and keys after its last attention."""
    keys, keys_pe, first_kv, first_q = image
    batch = tokens.shape[0]
    queries = tokens
    keys = keys.expand(batch, -1, -1)
    for index, layer in enumerate(transformer.layers):
        if index == 0:  # skip_first_layer_pe
            queries = layer.self_attn.o_proj(_self_attention(layer.self_attn, queries))
        else:
            query = queries + tokens
            queries = queries + _attention(layer.self_attn, query, query, queries)
        queries = layer.layer_norm1(queries)
        key_pe, kv = (keys_pe, first_kv) if index == 0 else (keys + image_pe, (None, None))
        queries = layer.layer_norm2(
            queries
            + _attention(layer.cross_attn_token_to_image, queries + tokens, key_pe, keys, kv)
        )
        queries = layer.layer_norm3(queries + layer.mlp(queries))
        token_side = queries + tokens
        cross = layer.cross_attn_image_to_token
        if index == 0 and first_q is not None:
            image_q = first_q.expand(batch, -1, -1)
        else:
            image_q = cross.q_proj(key_pe)
        keys = layer.layer_norm4(
            keys + _attend_projected_query(cross, image_q, token_side, queries)
        )
    final = transformer.final_attn_token_to_image
    queries = transformer.layer_norm_final_attn(
        queries + _attention(final, queries + tokens, keys + image_pe, keys)
    )
    return queries, keys


def _mask_head(
    decoder: Any, embedding: ImageEmbedding, queries: torch.Tensor, keys: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The decoder's heads: every mask token's low-res logits (upscaled image features ×
    hypernetwork), the predicted IoUs and the object-score logits."""
    batch = queries.shape[0]
    side = int(keys.shape[1] ** 0.5)
    image = keys.transpose(1, 2).reshape(batch, -1, side, side)
    s0, s1 = embedding.features[0], embedding.features[1]
    upscaled = decoder.upscale_conv1(image) + s1
    upscaled = decoder.activation(decoder.upscale_layer_norm(upscaled))
    upscaled = decoder.activation(decoder.upscale_conv2(upscaled) + s0)
    mask_tokens = queries[:, 2 : 2 + decoder.num_mask_tokens]
    hyper = torch.stack(
        [mlp(mask_tokens[:, i]) for i, mlp in enumerate(decoder.output_hypernetworks_mlps)],
        dim=1,
    )  # B × 4 × C/8
    _, channels, height, width = upscaled.shape
    masks = (hyper @ upscaled.view(batch, channels, height * width)).view(batch, -1, height, width)
    iou = decoder.iou_prediction_head(queries[:, 1])
    return masks, iou, decoder.pred_obj_score_head(queries[:, 0])[:, 0]


def decode_masks(
    model: Any,
    embedding: ImageEmbedding,
    image_pe: torch.Tensor,
    sparse: torch.Tensor,
    dense: torch.Tensor | None,
    multimask: bool,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """SAM2's mask decoder for a batch of B prompt sets (``sparse``: 1 × B × T × C).

    Returns low-res logits B × n × 256 × 256, predicted IoU B × n and object-score logits B.
    ``dense`` is the embedded previous mask (1 × C × 64 × 64) or None for "no mask", in which
    case the prompt-independent work is taken from the embedding's cache.
    """
    decoder = model.mask_decoder
    batch = sparse.shape[1]
    output_tokens = torch.cat(
        [decoder.obj_score_token.weight, decoder.iou_token.weight, decoder.mask_tokens.weight]
    )
    tokens = torch.cat([output_tokens.expand(batch, -1, -1), sparse[0]], dim=1)  # B × T' × C
    image = _image_keys(model, embedding, image_pe, dense)
    queries, keys = _two_way(decoder.transformer, tokens, image, image_pe)
    masks, iou, object_score = _mask_head(decoder, embedding, queries, keys)
    if multimask:
        return masks[:, 1:], iou[:, 1:], object_score
    if decoder.dynamic_multimask_via_stability:
        picked, picked_iou = decoder._dynamic_multimask_via_stability(masks[None], iou[None])
        return picked[0], picked_iou[0], object_score
    return masks[:, :1], iou[:, :1], object_score


def _self_attention(module: Any, queries: torch.Tensor) -> torch.Tensor:
    """Self-attention without the output projection (the first block's, without PE)."""
    batch = queries.shape[0]
    heads, dim = module.num_attention_heads, module.head_dim
    q = module.q_proj(queries).view(batch, -1, heads, dim).transpose(1, 2)
    k = module.k_proj(queries).view(batch, -1, heads, dim).transpose(1, 2)
    v = module.v_proj(queries).view(batch, -1, heads, dim).transpose(1, 2)
    out = F.scaled_dot_product_attention(q, k, v, scale=module.scaling)
    return out.transpose(1, 2).reshape(batch, -1, heads * dim)


def _attend_projected_query(
    module: Any, query: torch.Tensor, key: torch.Tensor, value: torch.Tensor
) -> torch.Tensor:
    """Image-to-token attention whose (large) query is already projected."""
    batch = key.shape[0]
    heads, dim = module.num_attention_heads, module.head_dim
    q = query.reshape(batch, -1, heads, dim).transpose(1, 2)
    k = module.k_proj(key).view(batch, -1, heads, dim).transpose(1, 2)
    v = module.v_proj(value).view(batch, -1, heads, dim).transpose(1, 2)
    out = F.scaled_dot_product_attention(q, k, v, scale=module.scaling)
    projected_out: torch.Tensor = module.o_proj(out.transpose(1, 2).reshape(batch, -1, heads * dim))
    return projected_out
