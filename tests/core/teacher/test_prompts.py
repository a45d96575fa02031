"""Prompt configurations on constructed attention maps."""

from __future__ import annotations

import numpy as np

from weldpool_core.teacher.dino import AttentionMaps
from weldpool_core.teacher.prompts import (
    PROMPT_STRATEGIES,
    HeuristicParams,
    center_prompts,
    heuristic_prompts,
    none_prompts,
)


def _maps(mean: np.ndarray, image_size=(400, 600)) -> AttentionMaps:
    mean = mean.astype(np.float32)
    return AttentionMaps(
        heads=mean[None],
        mean=mean,
        attended=mean > mean.mean(),
        cls=np.zeros(4, np.float32),
        image_size=image_size,
    )


def _blob(grid=(20, 30), centre=(10, 15), radius=4, peak=1.0) -> np.ndarray:
    rows, cols = np.mgrid[: grid[0], : grid[1]]
    distance = np.hypot(rows - centre[0], cols - centre[1])
    return np.where(distance <= radius, peak * (1.2 - distance / radius), 0.0) + 0.01


def test_registry_has_the_papers_three_configurations() -> None:
    assert set(PROMPT_STRATEGIES) == {"none", "center", "heuristic"}
    assert none_prompts(_maps(_blob())).empty


def test_center_is_the_centroid_of_the_attended_patches() -> None:
    prompts = center_prompts(_maps(_blob(centre=(5, 20))))
    ((x, y),) = prompts.points
    assert prompts.labels == (1,)
    assert abs(x - (20 + 0.5) * 600 / 30) < 1e-6 and abs(y - (5 + 0.5) * 400 / 20) < 1e-6


def test_heuristic_boxes_the_strongest_region_and_clicks_inside_and_outside() -> None:
    strong, weak = _blob(centre=(10, 8), radius=4, peak=2.0), _blob(centre=(10, 24), radius=3)
    attention = _maps(strong + weak)
    params = HeuristicParams(positive_points=3, negative_points=2)
    prompts = heuristic_prompts(attention, params)
    x0, y0, x1, y1 = prompts.box
    # The box holds the strong blob (columns 4..12 → x 80..260 plus margin), not the weak one.
    assert x0 < 4 * 20 and x1 > 13 * 20 and x1 < 21 * 20
    positives = [p for p, label in zip(prompts.points, prompts.labels, strict=True) if label]
    negatives = [p for p, label in zip(prompts.points, prompts.labels, strict=True) if not label]
    assert len(positives) == 3 and len(negatives) == 2
    assert all(x0 <= x <= x1 and y0 <= y <= y1 for x, y in positives)
    assert all(not (x0 <= x <= x1 and y0 <= y <= y1) for x, y in negatives)
    # The first positive is the strongest patch: the strong blob's centre.
    assert positives[0] == ((8 + 0.5) * 20, (10 + 0.5) * 20)
    # Positives keep their separation (3 patches = 60 px here).
    for i, a in enumerate(positives):
        for b in positives[i + 1 :]:
            assert np.hypot(a[0] - b[0], a[1] - b[1]) >= 60 - 1e-6


def test_heuristic_falls_back_to_center_without_a_region() -> None:
    scattered = np.full((20, 30), 0.01)
    scattered[::6, ::7] = 1.0  # isolated patches: DBSCAN finds no region
    attention = _maps(scattered)
    assert heuristic_prompts(attention) == center_prompts(attention)
    flat = _maps(np.full((20, 30), 0.5))
    assert center_prompts(flat).points == ((300.0, 200.0),)
