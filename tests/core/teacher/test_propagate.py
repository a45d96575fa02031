"""SAM2 propagation through a run on random weights: equal to transformers' own video loop,
equal with cached embeddings, memory bounded by what SAM2 can look back on."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from tests.models import tiny_sam2_pair
from weldpool_core.synth import SynthParams, synth_frame
from weldpool_core.teacher.cache import EmbeddingCache, cached_embedding

SIZE = SynthParams(width=96, height=64)


def _rgb(image: np.ndarray) -> np.ndarray:
    return np.repeat(image[:, :, None], 3, axis=2) if image.ndim == 2 else image


@pytest.fixture(scope="module")
def run() -> tuple[list[np.ndarray], np.ndarray]:
    """A short run of drifting synthetic pools, and the true mask of its frame 3."""
    frames = [synth_frame(seed=100 + i, params=SIZE) for i in range(14)]
    return [_rgb(f.image) for f in frames], frames[3].mask


@pytest.fixture(scope="module")
def pair():
    return tiny_sam2_pair(seed=3)


def _reference(propagator, predictor, frames, prompt_index, mask, reverse_too=True):
    """transformers' own loop: the whole video in the session, propagate_in_video_iterator."""
    from transformers.models.sam2_video.modeling_sam2_video import Sam2VideoInferenceSession

    video = torch.cat([predictor.preprocess(f) for f in frames])
    session = Sam2VideoInferenceSession(
        video=video,
        video_height=frames[0].shape[0],
        video_width=frames[0].shape[1],
        dtype=torch.float32,
    )
    obj_idx = session.obj_id_to_idx(1)
    session.add_mask_inputs(obj_idx, prompt_index, propagator.mask_input(mask))
    session.obj_with_new_inputs = [1]
    model = propagator.model
    ious: list[float] = []
    hook = model.mask_decoder.register_forward_hook(
        lambda _m, _i, outputs: ious.append(float(outputs[1].float().max()))
    )
    out = {}

    def keep(step) -> None:  # type: ignore[no-untyped-def]
        score = float(torch.sigmoid(step.object_score_logits.float().flatten()[0]))
        out[step.frame_idx] = (step.pred_masks[0, 0].float().numpy(), score, ious[-1])

    try:
        with torch.inference_mode():
            model(session, frame_idx=prompt_index)
            for step in model.propagate_in_video_iterator(session, start_frame_idx=prompt_index):
                keep(step)
            if reverse_too:
                for step in model.propagate_in_video_iterator(
                    session, start_frame_idx=prompt_index, reverse=True
                ):
                    keep(step)
    finally:
        hook.remove()
    return out


def test_propagation_equals_transformers_video_loop(pair, run) -> None:
    predictor, propagator = pair
    frames, mask = run
    ours = list(
        propagator.propagate(len(frames), {3: mask}, lambda i: predictor.set_image(frames[i]))
    )
    reference = _reference(propagator, predictor, frames, 3, mask)
    assert propagator.keep == 4  # the 9 frames after the prompt run past what it keeps
    assert [m.index for m in ours] == [*range(4, 14), 2, 1, 0]  # forward first, then back
    for item in ours:
        expected, object_score, iou = reference[item.index]
        assert np.allclose(item.low_res_logits, expected, atol=2e-3), item.index
        # The confidence is SAM2's own, frame by frame: object probability × predicted IoU.
        assert item.object_score == pytest.approx(object_score, abs=1e-4)
        assert item.iou == pytest.approx(iou, abs=1e-4)
        assert item.confidence == pytest.approx(object_score * iou, abs=1e-4)
        assert item.mask.shape == (64, 96)
        assert 0.0 <= item.object_score <= 1.0 and np.isfinite(item.iou)
        assert item.source_index == 3
        assert np.array_equal(item.low_res_logits > 0, expected > 0) or (
            np.mean((item.low_res_logits > 0) != (expected > 0)) < 1e-3
        )


def test_cached_embeddings_give_the_same_propagation(pair, run, tmp_path: Path) -> None:
    """Through the teacher's cache (written, then read back from disk by another cache)."""
    predictor, propagator = pair
    frames, mask = run
    fresh = list(propagator.propagate(8, {3: mask}, lambda i: predictor.set_image(frames[i])))
    EmbeddingCache(tmp_path)  # the cache directory a teacher run leaves
    for i in range(8):
        cached_embedding(
            predictor, EmbeddingCache(tmp_path), f"{i:064x}", lambda i=i: frames[i], (64, 96)
        )
    disk = EmbeddingCache(tmp_path)
    cached = list(
        propagator.propagate(
            8,
            {3: mask},
            lambda i: cached_embedding(predictor, disk, f"{i:064x}", lambda: None, (64, 96))[0],
        )
    )
    assert disk.hits["disk"] == 8 and disk.hits["miss"] == 0
    for a, b in zip(fresh, cached, strict=True):
        assert a.index == b.index and np.array_equal(a.low_res_logits, b.low_res_logits)


def test_memory_is_bounded_by_what_sam2_looks_back_on(pair, run) -> None:
    predictor, propagator = pair
    frames, mask = run
    sessions = []
    make = propagator.session
    propagator.session = lambda *a: sessions.append(make(*a)) or sessions[-1]  # type: ignore[method-assign]
    try:
        held = []
        for _ in propagator.propagate(
            20, {0: mask}, lambda i: predictor.set_image(frames[i % len(frames)]), "forward"
        ):
            held.append(len(sessions[0].output_dict_per_obj[0]["non_cond_frame_outputs"]))
    finally:
        del propagator.session
    assert max(held) <= 2 * propagator.keep + 1
    assert held[-1] == held[-6]  # flat, not growing with the run


def test_bad_prompts_are_refused(pair, run) -> None:
    from weldpool_core.errors import InvalidInputError

    predictor, propagator = pair
    frames, mask = run
    with pytest.raises(InvalidInputError, match="at least one"):
        list(propagator.propagate(5, {}, lambda i: predictor.set_image(frames[i])))
    with pytest.raises(InvalidInputError, match="not in the run"):
        list(propagator.propagate(5, {9: mask}, lambda i: predictor.set_image(frames[i])))


def test_propagation_runs_in_bf16_as_on_a_gpu(run) -> None:
    """The video model and the embeddings in bf16 (the GPU's inference precision): features,
    prompt masks and the session follow the model's dtype; the masks agree with fp32."""
    from tests.models import tiny_sam2_pair
    from weldpool_core.teacher.propagate import Sam2Propagator
    from weldpool_core.teacher.sam2 import Sam2Predictor

    predictor, propagator = tiny_sam2_pair(seed=3)
    frames, mask = run
    reference = list(propagator.propagate(5, {0: mask}, lambda i: predictor.set_image(frames[i])))
    half = Sam2Propagator(propagator.model.to(torch.bfloat16))
    half_predictor = Sam2Predictor(predictor.model.to(torch.bfloat16))
    assert half.dtype == half_predictor.dtype == torch.bfloat16
    ours = list(half.propagate(5, {0: mask}, lambda i: half_predictor.set_image(frames[i])))
    assert [m.index for m in ours] == [m.index for m in reference]
    for a, b in zip(ours, reference, strict=True):
        assert a.low_res_logits.dtype == np.float32 and np.isfinite(a.confidence)
        agreement = np.mean((a.low_res_logits > 0) == (b.low_res_logits > 0))
        assert agreement > 0.9, (a.index, agreement)


def test_the_video_model_borrows_the_image_models_vision_encoder(run, tmp_path: Path) -> None:
    """Loaded from one checkpoint through the loader, the video model holds the image model's
    vision encoder (one copy: the pair's distinct weights shrink by the encoder's) and
    propagates exactly as it does with its own; an image model from other weights is refused."""
    from weldpool_core.teacher.loader import load_sam2, load_sam2_video

    _, saved = tiny_sam2_pair(seed=5)
    saved.model.save_pretrained(tmp_path / "sam2")
    ref = str(tmp_path / "sam2")
    image = load_sam2(ref, "cpu")
    own = load_sam2_video(ref, "cpu")
    shared = load_sam2_video(ref, "cpu", image_model=image)
    assert shared.model.vision_encoder is image.model.vision_encoder
    assert own.model.vision_encoder is not image.model.vision_encoder

    def distinct(*models) -> int:  # type: ignore[no-untyped-def]
        seen = {id(p): p.numel() for m in models for p in m.parameters()}
        return sum(seen.values())

    encoder = sum(p.numel() for p in image.model.vision_encoder.parameters())
    assert encoder > 0
    assert distinct(image.model, shared.model) == distinct(image.model, own.model) - encoder

    frames, mask = run
    features = [image.set_image(f) for f in frames[:8]]
    a = list(own.propagate(8, {3: mask}, lambda i: features[i]))
    b = list(shared.propagate(8, {3: mask}, lambda i: features[i]))
    for x, y in zip(a, b, strict=True):
        assert x.index == y.index and np.array_equal(x.low_res_logits, y.low_res_logits)

    other, _ = tiny_sam2_pair(seed=6)
    with pytest.raises(ValueError, match="not from the video model's weights"):
        load_sam2_video(ref, "cpu", image_model=other)
