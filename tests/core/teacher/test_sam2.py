"""SAM2 processing and the predictor: our decoder equals transformers' Sam2Model, clicks never
re-encode the image, coordinates follow the frame."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tests.models import full_sam2, tiny_sam2
from weldpool_core.errors import InvalidInputError
from weldpool_core.teacher.sam2 import Prompts

FRAME = np.random.default_rng(3).integers(0, 256, (120, 160, 3), dtype=np.uint8)


def _reference(predictor, embedding, prompts: Prompts, multimask: bool):
    """Sam2Model.forward on the same embedding: the straightforward path."""
    height, width = embedding.image_size
    scale = torch.tensor([1024 / width, 1024 / height])
    kwargs = {}
    if prompts.points:
        kwargs["input_points"] = torch.tensor(prompts.points)[None, None] * scale
        kwargs["input_labels"] = torch.tensor(prompts.labels)[None, None]
    if prompts.box:
        kwargs["input_boxes"] = (torch.tensor(prompts.box).view(2, 2) * scale).view(1, 1, 4)
    if prompts.mask_logits is not None:
        kwargs["input_masks"] = torch.tensor(prompts.mask_logits)[None, None]
    with torch.inference_mode():
        out = predictor.model(
            image_embeddings=list(embedding.features), multimask_output=multimask, **kwargs
        )
    logits, iou = out.pred_masks[0, 0], out.iou_scores[0, 0]
    order = torch.argsort(iou, descending=True)
    return logits[order].numpy(), iou[order].numpy()


@pytest.fixture(scope="module")
def predictor():
    return tiny_sam2()


@pytest.fixture(scope="module")
def embedding(predictor):
    return predictor.set_image(FRAME)


@pytest.mark.parametrize("multimask", [True, False])
@pytest.mark.parametrize(
    "prompts",
    [
        Prompts(((80.0, 60.0),), (1,)),
        Prompts(((80.0, 60.0), (10.0, 100.0)), (1, 0)),
        Prompts(box=(20.0, 15.0, 140.0, 110.0)),
        Prompts(((80.0, 60.0),), (1,), box=(20.0, 15.0, 140.0, 110.0)),
    ],
)
def test_decoder_equals_sam2model(predictor, embedding, prompts, multimask) -> None:
    ours = predictor.predict(embedding, prompts, multimask=multimask)
    logits, iou = _reference(predictor, embedding, prompts, multimask)
    assert np.abs(logits).max() > 0.1  # random weights, but not a trivial output
    np.testing.assert_allclose(ours.low_res_logits, logits, atol=1e-4, rtol=1e-4)
    np.testing.assert_allclose(ours.scores, iou, atol=1e-5)


def test_decoder_with_a_previous_mask_equals_sam2model(predictor, embedding) -> None:
    first = predictor.predict(embedding, Prompts(((80.0, 60.0),), (1,)))
    again = Prompts(((80.0, 60.0), (30.0, 30.0)), (1, 0), mask_logits=first.low_res_logits[0])
    ours = predictor.predict(embedding, again, multimask=False)
    logits, _ = _reference(predictor, embedding, again, False)
    np.testing.assert_allclose(ours.low_res_logits, logits, atol=1e-4, rtol=1e-4)


def test_clicks_after_set_image_never_run_the_image_encoder(predictor) -> None:
    calls = []
    # The encoder's first layer (the encoder itself runs as hiera.ImageEncoder, not forward).
    stem = predictor.model.vision_encoder.backbone.patch_embed.projection
    hook = stem.register_forward_hook(lambda *a: calls.append(1))
    try:
        embedding = predictor.set_image(FRAME)
        assert len(calls) == 1
        for x in (20.0, 60.0, 100.0):
            predictor.predict(embedding, Prompts(((x, 50.0),), (1,)))
        predictor.predict(embedding, Prompts(box=(10.0, 10.0, 90.0, 90.0)))
        assert len(calls) == 1
    finally:
        hook.remove()


def test_masks_come_back_at_frame_size_best_first(predictor, embedding) -> None:
    prediction = predictor.predict(embedding, Prompts(((80.0, 60.0),), (1,)))
    assert prediction.mask.shape == (120, 160) and prediction.mask.dtype == bool
    assert prediction.low_res_logits.shape == (3, 256, 256)
    assert list(prediction.scores) == sorted(prediction.scores, reverse=True)
    single = predictor.predict(embedding, Prompts(((80.0, 60.0), (5.0, 5.0)), (1, 0)))
    assert single.low_res_logits.shape == (1, 256, 256)  # several points: one mask


def test_coordinates_scale_with_the_frame(predictor) -> None:
    """x scales by 1024 / width and y by 1024 / height (SAM2 squeezes the frame to 1024²):
    on a 160 wide × 120 high frame a click at (40, 90) is at (256, 768); swapped scales or
    swapped axes give other numbers."""
    from weldpool_core.teacher.sam2 import input_coordinates

    points = torch.tensor([[40.0, 90.0], [160.0, 0.0]])
    expected = torch.tensor([[256.0, 768.0], [1024.0, 0.0]])
    torch.testing.assert_close(input_coordinates(points, (120, 160)), expected)
    sparse = predictor._sparse(Prompts(((40.0, 90.0),), (1,)), (120, 160))
    direct = predictor.model.prompt_encoder._embed_points(
        expected[:1][None, None], torch.ones(1, 1, 1, dtype=torch.int64), pad=True
    )
    torch.testing.assert_close(sparse, direct)
    large = np.repeat(np.repeat(FRAME, 2, axis=0), 2, axis=1)
    b = predictor.predict(predictor.set_image(large), Prompts(((80.0, 180.0),), (1,)))
    assert b.mask.shape == (240, 320)


def test_batched_grid_clicks_equal_sam2model_one_by_one(predictor, embedding) -> None:
    """The automatic mode's batched clicks (``predict_points``): each equals Sam2Model's own
    forward on that click alone, on a non-square frame (so x/y mix-ups show)."""
    grid = np.array([[10.0, 100.0], [150.0, 20.0], [80.0, 60.0], [120.0, 110.0]], np.float32)
    low_res, iou, objects = predictor.predict_points(embedding, grid)
    assert low_res.shape == (4, 3, 256, 256) and iou.shape == (4, 3) and objects.shape == (4,)
    for index, (x, y) in enumerate(grid):
        logits, scores = _reference(
            predictor, embedding, Prompts(((float(x), float(y)),), (1,)), True
        )
        order = torch.argsort(iou[index], descending=True)
        np.testing.assert_allclose(low_res[index][order].numpy(), logits, atol=1e-4, rtol=1e-4)
        np.testing.assert_allclose(iou[index][order].numpy(), scores, atol=1e-5)


@pytest.mark.parametrize("dtype", [torch.bfloat16, torch.float16])
def test_half_precision_decoder_follows_the_fp32_reference(predictor, dtype) -> None:
    """On a GPU the models run in bf16 (fp16 on older cards): the fast decoder in that
    precision stays close to Sam2Model's fp32 forward, for single and batched prompts."""
    import copy

    from weldpool_core.teacher.sam2 import Sam2Predictor

    half = Sam2Predictor(copy.deepcopy(predictor.model).to(dtype))
    embedding = half.set_image(FRAME)
    assert embedding.features[2].dtype == dtype
    full = Sam2Predictor(copy.deepcopy(predictor.model))
    reference = full.set_image(FRAME)
    for prompts in (
        Prompts(((80.0, 60.0),), (1,)),
        Prompts(((80.0, 60.0), (10.0, 100.0)), (1, 0), box=(20.0, 15.0, 140.0, 110.0)),
    ):
        ours = half.predict(embedding, prompts)
        logits, iou = _reference(full, reference, prompts, len(prompts.points) == 1)
        scale = float(np.abs(logits).max())
        np.testing.assert_allclose(ours.low_res_logits, logits, atol=0.05 * scale)
        np.testing.assert_allclose(ours.scores, iou, atol=0.05)
    low_res, _, _ = half.predict_points(embedding, np.array([[80.0, 60.0], [10.0, 100.0]]))
    logits, _ = _reference(full, reference, Prompts(((10.0, 100.0),), (1,)), True)
    ours_batched = low_res[1].numpy()
    for candidate in logits:  # each reference candidate has its match among ours
        closest = min(float(np.abs(o - candidate).max()) for o in ours_batched)
        assert closest < 0.05 * float(np.abs(logits).max())


def test_bad_prompts_are_clear_errors(predictor, embedding) -> None:
    with pytest.raises(InvalidInputError, match="needs a label"):
        Prompts(((1.0, 2.0),), ())
    with pytest.raises(InvalidInputError, match="x0 < x1"):
        Prompts(box=(10.0, 10.0, 5.0, 20.0))
    with pytest.raises(InvalidInputError, match="at least one point"):
        predictor.predict(embedding, Prompts())
    with pytest.raises(InvalidInputError, match="256×256"):
        predictor.predict(embedding, Prompts(mask_logits=np.zeros((64, 64), np.float32)))


@pytest.mark.slow
def test_full_size_sam2_hiera_tiny_end_to_end() -> None:
    predictor = full_sam2()
    frame = np.random.default_rng(0).integers(0, 256, (800, 1280, 3), dtype=np.uint8)
    embedding = predictor.set_image(frame)
    assert [tuple(f.shape) for f in embedding.features] == [
        (1, 32, 256, 256),
        (1, 64, 128, 128),
        (1, 256, 64, 64),
    ]
    prompts = Prompts(((640.0, 400.0), (100.0, 100.0)), (1, 0), box=(300.0, 200.0, 1000.0, 650.0))
    ours = predictor.predict(embedding, prompts, multimask=False)
    logits, _ = _reference(predictor, embedding, prompts, False)
    np.testing.assert_allclose(ours.low_res_logits, logits, atol=1e-4, rtol=1e-4)
    assert ours.mask.shape == (800, 1280)
