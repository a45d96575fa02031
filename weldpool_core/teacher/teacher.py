"""The teacher: DINO attention → prompts → SAM2 mask → Algorithm 1 heatmap and keypoints."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from weldpool_core.errors import InvalidInputError
from weldpool_core.teacher.cache import EmbeddingCache, cached_embedding
from weldpool_core.teacher.dino import AttentionMaps, DinoAttention
from weldpool_core.teacher.prompt_names import DEFAULT_PROMPTS, PromptName
from weldpool_core.teacher.prompts import PROMPT_STRATEGIES, HeuristicParams
from weldpool_core.teacher.sam2 import (
    ImageEmbedding,
    MaskPrediction,
    Prompts,
    Sam2Predictor,
)
from weldpool_core.teacher.weights import weights_name


@dataclass(frozen=True)
class TeacherConfig:
    """How the teacher proposes a mask.

    Attributes:
        prompts: ``none``, ``center`` or ``heuristic`` (default; the paper's best).
        heuristic: parameters of the heuristic prompts.
        grid_points: for ``none``: SAM2's automatic mode clicks an n×n grid (default 8, i.e.
            64 candidate prompts; the paper's SAM2 default of 32×32 costs 16× more on CPU).
        grid_batch: grid prompts decoded together.
        stability_threshold: automatic-mode candidates whose stability score (IoU of the mask
            at logit thresholds +1 and −1) is below this are passed over when others pass.
        heatmap_k: keypoints per frame for Algorithm 1.
        stability_samples: how many jittered copies of the prompts are decoded to measure how
            stable the mask is (0 turns it off); each costs one decoder pass.
        stability_jitter: the jitter's standard deviation, as a fraction of the frame's longer
            side (points move, box corners move).
    """

    prompts: PromptName = DEFAULT_PROMPTS
    heuristic: HeuristicParams = field(default_factory=HeuristicParams)
    grid_points: int = 8
    grid_batch: int = 16
    stability_threshold: float = 0.9
    heatmap_k: int = 4
    stability_samples: int = 4
    stability_jitter: float = 0.02

    def __post_init__(self) -> None:
        if self.prompts not in PROMPT_STRATEGIES:
            raise InvalidInputError(
                f"Unknown prompt configuration {self.prompts!r}; use none, center or heuristic."
            )


@dataclass(frozen=True)
class TeacherResult:
    """Everything the teacher proposes for one frame.

    ``heatmap`` is Algorithm 1's H×W×2 array and ``keypoints`` its k (x, y) points; both are
    None with a ``warning`` when the mask is empty or too small for Algorithm 1.
    """

    mask: NDArray[np.bool_]
    score: float
    object_score: float
    prompts: Prompts
    attention: AttentionMaps
    heatmap: NDArray[np.float32] | None
    keypoints: list[list[float]]
    keypoint_rules: list[str]
    low_res_logits: NDArray[np.float32]
    timings: dict[str, float]
    warning: str | None = None
    prompt_stability: float | None = None


class Teacher:
    """Owns DINO, SAM2 and the embedding cache; ``run`` proposes a mask for one frame.

    Args:
        dino: DINO attention maps.
        sam2: the SAM2 predictor.
        sam2_id: names the SAM2 weights in cache keys (a hub id or a directory).
        cache: the embedding cache shared with the click endpoint; None caches nothing.
        config: prompt configuration and parameters.
    """

    def __init__(
        self,
        dino: DinoAttention,
        sam2: Sam2Predictor,
        sam2_id: str,
        cache: EmbeddingCache | None = None,
        config: TeacherConfig | None = None,
        dino_id: str = "dino",
    ) -> None:
        self.dino_id = dino_id
        self.dino = dino
        self.sam2 = sam2
        self.sam2_id = sam2_id
        self.cache = cache
        self.config = config or TeacherConfig()

    @classmethod
    def load(
        cls,
        dino_ref: str,
        sam2_ref: str,
        *,
        device: str = "auto",
        cache_dir: Path | None = None,
        config: TeacherConfig | None = None,
        dino_input_size: int = 480,
    ) -> Teacher:
        """Load both models from hub ids (already fetched) or local directories.

        Raises WeightsUnavailableError naming WELDPOOL_DINO / WELDPOOL_SAM2 when missing.
        """
        from weldpool_core.teacher.loader import load_dino, load_sam2
        from weldpool_core.teacher.weights import resolve_weights

        resolve_weights(dino_ref, "WELDPOOL_DINO")  # both are checked before either loads
        resolve_weights(sam2_ref, "WELDPOOL_SAM2")
        dino = load_dino(dino_ref, device, dino_input_size)
        sam2 = load_sam2(sam2_ref, device)
        return cls(
            dino,
            sam2,
            sam2_ref,
            EmbeddingCache(cache_dir) if cache_dir else EmbeddingCache(None),
            config,
            dino_ref,
        )

    @property
    def model_id(self) -> str:
        """Names this teacher's output: its models by their weights' content when it loaded
        them (``weights_identity``: a hub id and revision, or a hash; never a local path), else
        by name; DINO's input size and the prompt configuration. The same on every worker with
        the same weights, whatever their folders are called."""
        dino = self.dino.weights_id or weights_name(self.dino_id)
        sam2 = self.sam2.identity or weights_name(self.sam2_id)
        return f"{dino}@{self.dino.input_size}+{sam2}+{self.config.prompts}"

    def embedding(
        self, image: NDArray[np.uint8], image_sha256: str | None = None
    ) -> ImageEmbedding:
        """SAM2's embedding of ``image``, from the cache when ``image_sha256`` is known."""
        embedding, _ = cached_embedding(
            self.sam2, self.cache, image_sha256, lambda: image, (image.shape[0], image.shape[1])
        )
        return embedding

    def run(
        self,
        image: NDArray[np.uint8],
        image_sha256: str | None = None,
        between: Callable[[], None] | None = None,
    ) -> TeacherResult:
        """Propose a mask, heatmap and keypoints for one RGB uint8 frame.

        ``between`` is called after each heavy stage (DINO, SAM2's encoder); raise from it to
        stop a run early (a cancelled job waits for one stage, not for the whole frame)."""
        start = time.perf_counter()
        attention = self.dino(image)
        dino_s = time.perf_counter() - start
        if between is not None:
            between()
        mark = time.perf_counter()
        embedding = self.embedding(image, image_sha256)
        encode_s = time.perf_counter() - mark
        if between is not None:
            between()
        return self.propose(
            attention, embedding, self.config.prompts, {"dino_s": dino_s, "sam2_encode_s": encode_s}
        )

    def run_many(
        self,
        images: list[NDArray[np.uint8]],
        image_sha256s: list[str | None] | None = None,
        between: Callable[[], None] | None = None,
    ) -> list[TeacherResult]:
        """``run`` on several frames, with DINO and SAM2's encoder each in one batch (the frames
        the embedding cache lacks): what a GPU worker's teacher run does with a chunk. The same
        proposals as ``run`` one frame at a time, up to the batched kernels' rounding; each
        frame's timings are its share of the batch."""
        shas = image_sha256s or [None] * len(images)
        start = time.perf_counter()
        attentions = self.dino.many(images)
        dino_s = (time.perf_counter() - start) / len(images)
        if between is not None:
            between()
        mark = time.perf_counter()
        embeddings = self._embeddings(images, shas)
        encode_s = (time.perf_counter() - mark) / len(images)
        if between is not None:
            between()
        timings = {"dino_s": dino_s, "sam2_encode_s": encode_s}
        return [
            self.propose(attention, embedding, self.config.prompts, timings)
            for attention, embedding in zip(attentions, embeddings, strict=True)
        ]

    def _embeddings(
        self, images: list[NDArray[np.uint8]], shas: list[str | None]
    ) -> list[ImageEmbedding]:
        """Each frame's SAM2 embedding: from the cache where it holds one, the others encoded
        in one batch and cached."""
        from weldpool_core.teacher.cache import embedding_key

        keys = [
            None
            if self.cache is None or sha is None
            else embedding_key(sha, self.sam2.cache_identity)
            for sha in shas
        ]
        found: dict[int, ImageEmbedding] = {}
        for index, key in enumerate(keys):
            if key is not None and self.cache is not None:
                hit = self.cache.get(key, self.sam2.device, self.sam2.dtype)
                if hit is not None and hit.image_size == images[index].shape[:2]:
                    found[index] = hit
        missing = [index for index in range(len(images)) if index not in found]
        if missing:
            encoded = self.sam2.set_images([images[index] for index in missing])
            for index, embedding in zip(missing, encoded, strict=True):
                found[index] = embedding
                if keys[index] is not None and self.cache is not None:
                    self.cache.put(keys[index], embedding)  # type: ignore[arg-type]
        return [found[index] for index in range(len(images))]

    def propose(
        self,
        attention: AttentionMaps,
        embedding: ImageEmbedding,
        prompt_config: PromptName,
        timings: dict[str, float] | None = None,
    ) -> TeacherResult:
        """The prompt → mask → heatmap part, on attention and an embedding already computed
        (``weldpool eval teacher`` compares the three configurations on the same frame)."""
        from weldpool_core.heatmap import HeatmapParams, heatmap_from_mask

        timings = dict(timings or {})
        mark = time.perf_counter()
        strategy = PROMPT_STRATEGIES[prompt_config]
        prompts = strategy(attention, self.config.heuristic)
        prediction = (
            self._automatic(embedding) if prompts.empty else self.sam2.predict(embedding, prompts)
        )
        mask = prediction.mask
        stability = (
            None if prompts.empty else self._prompt_stability(embedding, prompts, prediction)
        )
        timings["sam2_decode_s"] = time.perf_counter() - mark

        mark = time.perf_counter()
        heatmap, keypoints, rules, warning = None, [], [], None
        try:
            result = heatmap_from_mask(mask, HeatmapParams(k=self.config.heatmap_k))
        except InvalidInputError as exc:
            warning = f"No keypoints: {exc.message}"
        else:
            heatmap = result.heatmap
            keypoints = [[float(x), float(y)] for x, y in np.asarray(result.keypoints)]
            rules = [str(rule) for rule in result.rules]
        timings["heatmap_s"] = time.perf_counter() - mark
        timings["total_s"] = sum(timings.values())
        return TeacherResult(
            mask=mask,
            score=prediction.score,
            object_score=prediction.object_score,
            prompts=prompts,
            attention=attention,
            heatmap=heatmap,
            keypoints=keypoints,
            keypoint_rules=rules,
            low_res_logits=prediction.low_res_logits[0],
            timings=timings,
            warning=warning,
            prompt_stability=stability,
        )

    def _prompt_stability(
        self, embedding: ImageEmbedding, prompts: Prompts, prediction: MaskPrediction
    ) -> float | None:
        """Mean IoU between the mask and the masks of jittered prompts (1: perfectly stable).

        Compared on SAM2's 256×256 grid; the jitter is seeded, so the score is reproducible.
        """
        samples = self.config.stability_samples
        if samples < 1:
            return None
        height, width = embedding.image_size
        sigma = self.config.stability_jitter * max(height, width)
        rng = np.random.default_rng(0)
        reference = prediction.low_res_logits[0] > 0
        scores = []
        for _ in range(samples):
            points = tuple(
                (
                    float(np.clip(x + rng.normal(0, sigma), 0, width)),
                    float(np.clip(y + rng.normal(0, sigma), 0, height)),
                )
                for x, y in prompts.points
            )
            box = None
            if prompts.box is not None:
                x0, y0, x1, y1 = (v + rng.normal(0, sigma) for v in prompts.box)
                box = (min(x0, x1 - 1), min(y0, y1 - 1), max(x1, x0 + 1), max(y1, y0 + 1))
            jittered = self.sam2.predict(embedding, Prompts(points, prompts.labels, box))
            other = jittered.low_res_logits[0] > 0
            union = np.logical_or(reference, other).sum()
            scores.append(1.0 if union == 0 else np.logical_and(reference, other).sum() / union)
        return float(np.mean(scores))

    @torch.inference_mode()
    def _automatic(self, embedding: ImageEmbedding) -> MaskPrediction:
        """SAM2 without prompts: click an n×n grid, keep the best stable candidate."""
        height, width = embedding.image_size
        n = self.config.grid_points
        xs = (np.arange(n) + 0.5) * width / n
        ys = (np.arange(n) + 0.5) * height / n
        grid = np.array([[x, y] for y in ys for x in xs], np.float32)  # frame pixels
        best: tuple[float, float, Any, Any, float] | None = None
        for start in range(0, len(grid), self.config.grid_batch):
            low_res, iou, objects = self.sam2.predict_points(
                embedding, grid[start : start + self.config.grid_batch]
            )
            stability = _stability(low_res)
            for b in range(low_res.shape[0]):
                for c in range(low_res.shape[1]):
                    stable = float(stability[b, c]) >= self.config.stability_threshold
                    rank = (stable, float(iou[b, c]))
                    if best is None or rank > best[:2]:
                        best = (*rank, low_res[b, c], iou[b, c], float(objects[b]))
        assert best is not None
        return MaskPrediction(
            low_res_logits=best[2][None].cpu().numpy(),
            scores=np.array([float(best[3])], np.float32),
            object_score=best[4],
            image_size=embedding.image_size,
        )


def _stability(logits: torch.Tensor, offset: float = 1.0) -> torch.Tensor:
    """SAM's stability score: IoU of the masks at logit thresholds +offset and −offset."""
    inner = (logits > offset).flatten(-2).sum(-1).float()
    outer = (logits > -offset).flatten(-2).sum(-1).float()
    return torch.where(outer > 0, inner / outer.clamp(min=1), torch.ones_like(outer))
