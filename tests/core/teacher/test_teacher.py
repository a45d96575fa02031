"""The whole teacher on random weights: plumbing, cache reuse, configurations, loading."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from tests.helpers import SHARED_DATA
from tests.models import full_dino, full_sam2, tiny_dino, tiny_sam2
from weldpool_core.errors import InvalidInputError, WeightsUnavailableError
from weldpool_core.io import load_rgb8
from weldpool_core.synth import synth_frame
from weldpool_core.teacher.cache import EmbeddingCache
from weldpool_core.teacher.teacher import Teacher, TeacherConfig


def _rgb(image: np.ndarray) -> np.ndarray:
    return np.repeat(image[:, :, None], 3, axis=2) if image.ndim == 2 else image


@pytest.fixture(scope="module")
def frame() -> np.ndarray:
    return _rgb(synth_frame(seed=1).image)


@pytest.fixture(scope="module")
def models():
    return tiny_dino(input_size=64), tiny_sam2()


@pytest.mark.parametrize("prompts", ["heuristic", "center", "none"])
def test_run_gives_a_full_proposal(models, frame, prompts: str) -> None:
    dino, sam2 = models
    teacher = Teacher(dino, sam2, "tiny-sam2", config=TeacherConfig(prompts=prompts, grid_points=3))
    result = teacher.run(frame)
    height, width = frame.shape[:2]
    assert result.mask.shape == (height, width) and result.mask.dtype == bool
    assert 0.0 <= result.score <= 1.0
    assert result.low_res_logits.shape == (256, 256)
    assert result.attention.image_size == (height, width)
    if prompts == "none":
        assert result.prompts.empty
    else:
        assert result.prompts.labels[0] == 1
    assert set(result.timings) == {
        "dino_s",
        "sam2_encode_s",
        "sam2_decode_s",
        "heatmap_s",
        "total_s",
    }
    if result.heatmap is not None:  # random weights may give a mask Algorithm 1 refuses
        assert result.heatmap.shape == (height, width, 2)
        assert np.array_equal(result.heatmap[:, :, 1] > 0.5, result.mask)
        assert len(result.keypoints) == 4
    else:
        assert result.warning and result.keypoints == []
    assert teacher.model_id == f"dino@64+tiny-sam2+{prompts}"


def test_second_run_reuses_the_cached_embedding(models, frame, tmp_path: Path) -> None:
    dino, sam2 = models
    cache = EmbeddingCache(tmp_path)
    teacher = Teacher(dino, sam2, "tiny-sam2", cache)
    calls = []
    hook = sam2.model.vision_encoder.backbone.patch_embed.projection.register_forward_hook(
        lambda *a: calls.append(1)
    )
    try:
        first = teacher.run(frame, image_sha256="f" * 64)
        second = teacher.run(frame, image_sha256="f" * 64)
    finally:
        hook.remove()
    assert len(calls) == 1 and cache.hits["memory"] == 1
    assert np.array_equal(first.mask, second.mask)
    fresh = Teacher(dino, sam2, "tiny-sam2", EmbeddingCache(tmp_path))  # another process
    assert fresh.embedding(frame, "f" * 64) is not None and fresh.cache.hits["disk"] == 1


def test_a_run_stops_after_the_stage_where_it_is_asked_to(models, frame) -> None:
    """`between` runs after DINO and after SAM2's encoder; raising there skips what follows
    (a cancelled job waits for one stage, not for the whole frame)."""
    dino, sam2 = models
    teacher = Teacher(dino, sam2, "tiny-sam2")
    encoded = []
    hook = sam2.model.vision_encoder.backbone.patch_embed.projection.register_forward_hook(
        lambda *a: encoded.append(1)
    )

    class Stop(Exception):
        pass

    def stop_after(n: int):
        calls = []

        def between() -> None:
            calls.append(1)
            if len(calls) == n:
                raise Stop

        return between, calls

    try:
        between, calls = stop_after(1)
        with pytest.raises(Stop):
            teacher.run(frame, between=between)
        assert encoded == [] and len(calls) == 1  # stopped after DINO, before SAM2's encoder
        between, calls = stop_after(3)
        teacher.run(frame, between=between)
        assert len(encoded) == 1 and len(calls) == 2  # both stages, then the cheap rest
    finally:
        hook.remove()


def test_unknown_prompt_configuration_is_refused() -> None:
    with pytest.raises(InvalidInputError, match="none, center or heuristic"):
        TeacherConfig(prompts="magic")


def test_load_from_local_directories(models, frame, tmp_path: Path) -> None:
    dino, sam2 = models
    dino.model.save_pretrained(tmp_path / "dino")
    sam2.model.save_pretrained(tmp_path / "sam2")
    teacher = Teacher.load(
        str(tmp_path / "dino"),
        str(tmp_path / "sam2"),
        device="cpu",
        cache_dir=tmp_path / "cache",
        dino_input_size=64,
    )
    loaded = teacher.run(frame, "a" * 64)
    original = Teacher(dino, sam2, "x").run(frame)
    assert np.array_equal(loaded.mask, original.mask)  # the same weights came back


def test_a_loaded_teacher_is_named_by_its_weights_content(models, tmp_path: Path) -> None:
    """Two workers holding the same weights in folders of other names and places propose under
    one model_id (a retried run skips what the first proposed); other weights in a folder of the
    same name do not; no path is in it."""
    dino, sam2 = models
    for folder in ("one/dino", "two/dino-copy"):
        dino.model.save_pretrained(tmp_path / folder)
    for folder in ("one/sam2", "two/sam2-copy"):
        sam2.model.save_pretrained(tmp_path / folder)

    def model_id(where: str, dino_folder: str, sam2_folder: str) -> str:
        teacher = Teacher.load(
            str(tmp_path / where / dino_folder),
            str(tmp_path / where / sam2_folder),
            device="cpu",
            dino_input_size=64,
        )
        return teacher.model_id

    first = model_id("one", "dino", "sam2")
    assert first == model_id("two", "dino-copy", "sam2-copy")
    assert str(tmp_path) not in first and "sam2" not in first.split("+")[1]
    with torch.no_grad():  # other SAM2 weights, saved under the first folder's name
        next(sam2.model.parameters()).add_(1.0)
    sam2.model.save_pretrained(tmp_path / "three" / "sam2")
    dino.model.save_pretrained(tmp_path / "three" / "dino")
    other = model_id("three", "dino", "sam2")
    assert other.split("+")[0] == first.split("+")[0] and other != first


def test_missing_weights_name_the_variable(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    with pytest.raises(WeightsUnavailableError, match="WELDPOOL_DINO"):
        Teacher.load(str(tmp_path / "nothing"), "facebook/sam2.1-hiera-tiny")
    (tmp_path / "dino").mkdir()
    (tmp_path / "dino" / "config.json").write_text("{}")
    (tmp_path / "dino" / "model.safetensors").write_bytes(b"")
    with pytest.raises(WeightsUnavailableError, match="WELDPOOL_SAM2"):
        Teacher.load(str(tmp_path / "dino"), "facebook/sam2.1-hiera-tiny")


@pytest.mark.slow
def test_full_size_teacher_on_a_real_frame() -> None:
    frames = sorted((SHARED_DATA / "waam" / "frames").glob("*.png"))
    if not frames:
        pytest.skip("../shared/data/waam/frames is absent (a fresh checkout has no ../shared)")
    image = load_rgb8(frames[len(frames) // 2])
    teacher = Teacher(full_dino(480), full_sam2(), "facebook/sam2.1-hiera-tiny")
    result = teacher.run(image)
    assert result.mask.shape == (800, 1280)
    assert result.attention.heads.shape == (6, 60, 60)
    assert result.prompts.box is not None  # heuristic prompts found a region
    assert result.timings["total_s"] > 0


def test_prompt_stability_is_reproducible_and_bounded(models, frame) -> None:
    dino, sam2 = models
    teacher = Teacher(dino, sam2, "s", config=TeacherConfig(prompts="heuristic"))
    first, second = teacher.run(frame), teacher.run(frame)
    assert first.prompt_stability is not None and 0.0 <= first.prompt_stability <= 1.0
    assert first.prompt_stability == second.prompt_stability
    still = Teacher(dino, sam2, "s", config=TeacherConfig(stability_jitter=0.0)).run(frame)
    assert still.prompt_stability == 1.0  # no jitter: the same prompts give the same mask
    shaky = Teacher(dino, sam2, "s", config=TeacherConfig(stability_jitter=0.3)).run(frame)
    assert shaky.prompt_stability is not None and shaky.prompt_stability < 0.99  # it moved
    off = Teacher(dino, sam2, "s", config=TeacherConfig(stability_samples=0)).run(frame)
    assert off.prompt_stability is None
    automatic = Teacher(dino, sam2, "s", config=TeacherConfig(prompts="none", grid_points=2))
    assert automatic.run(frame).prompt_stability is None  # no prompts to jitter


def test_automatic_mode_clicks_a_grid_in_frame_pixels(models) -> None:
    """The ``none`` prompts click an n×n grid over the frame: x across the width, y down the
    height (a 160 wide × 120 high frame tells them apart), and keep the best stable candidate."""
    dino, sam2 = models
    teacher = Teacher(dino, sam2, "s", config=TeacherConfig(prompts="none", grid_points=3))
    embedding = sam2.set_image(np.random.default_rng(2).integers(0, 256, (120, 160, 3), np.uint8))
    clicked: list[np.ndarray] = []
    decoded: list[tuple] = []
    real = sam2.predict_points

    def recording(embedding, points):  # type: ignore[no-untyped-def]
        clicked.append(np.asarray(points))
        out = real(embedding, points)
        decoded.append(out)
        return out

    sam2.predict_points = recording  # type: ignore[method-assign]
    try:
        best = teacher._automatic(embedding)
    finally:
        del sam2.predict_points
    grid = np.concatenate(clicked)
    expected = [[(i + 0.5) * 160 / 3, (j + 0.5) * 120 / 3] for j in range(3) for i in range(3)]
    np.testing.assert_allclose(grid, expected, rtol=1e-6)
    ious = np.concatenate([iou.numpy() for _, iou, _ in decoded])
    assert np.isclose(ious, best.score).any()  # the kept mask is one of the grid's candidates


def test_a_batch_proposes_what_one_frame_at_a_time_does_and_fills_the_cache(
    models, tmp_path: Path
) -> None:
    """``run_many`` (a GPU worker's chunk) batches DINO and SAM2's encoder: per frame the same
    attention, mask, keypoints and scores as ``run``, frames of other sizes in one batch; it
    encodes only what the cache lacks and leaves every embedding there."""
    dino, sam2 = models
    frames = [_rgb(synth_frame(seed=seed).image) for seed in (2, 3)]
    frames.append(np.ascontiguousarray(frames[0][:, ::-1][:96, :128]))  # another size
    shas = [f"{seed:064x}" for seed in range(len(frames))]
    single = Teacher(dino, sam2, "tiny-sam2", EmbeddingCache(None))
    one_by_one = [single.run(frame) for frame in frames]
    cache = EmbeddingCache(tmp_path / "cache")
    batched = Teacher(dino, sam2, "tiny-sam2", cache)
    encoded = []
    hook = sam2.model.vision_encoder.backbone.patch_embed.projection.register_forward_hook(
        lambda _module, inputs, _output: encoded.append(inputs[0].shape[0])
    )
    try:
        together = batched.run_many(frames, shas)
        assert encoded == [3]  # one batch of three
        again = batched.run_many(frames, shas)
        assert encoded == [3]  # every embedding from the cache
    finally:
        hook.remove()
    for alone, batch, repeat in zip(one_by_one, together, again, strict=True):
        assert np.allclose(batch.attention.mean, alone.attention.mean, atol=1e-5)
        assert np.allclose(batch.low_res_logits, alone.low_res_logits, atol=1e-3)
        assert (batch.mask != alone.mask).mean() < 1e-3
        assert batch.mask.shape == alone.mask.shape and np.array_equal(repeat.mask, batch.mask)
        assert batch.score == pytest.approx(alone.score, abs=1e-4)
        assert np.allclose(batch.keypoints, alone.keypoints, atol=1.0)
