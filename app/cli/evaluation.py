"""Algorithm 1 on mask files, and scoring predictions against ground truth."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import click

from app.cli.base import fail, friendly_errors, image_files, load_settings, main, named_files
from weldpool_core.teacher.prompt_names import PromptName

# Masks are PNG files (0 / 255). A file `<stem>_mask.png` (what `teacher` and `predict` write)
# counts as the mask of `<stem>`, so outputs and ground truth line up by stem. A folder holding a
# `masks/` (or `keypoints/`) subfolder is read as a DATASET folder.


def _stem(path: Path) -> str:
    return path.stem.removesuffix("_mask")


def _input_masks(inputs: tuple[str, ...]) -> list[Path]:
    """The PNG masks named on the command line, folders expanded (sorted by name)."""
    return named_files(inputs, {".png"}, "PNG mask", _stem)


def _part(folder: Path, part: str) -> Path:
    """``folder/part`` when ``folder`` is a DATASET folder, else ``folder`` itself."""
    if not folder.is_dir():
        fail(f"{folder} is not a folder.")
    return folder / part if (folder / part).is_dir() else folder


@main.command("heatmap")
@click.argument("masks", nargs=-1, required=True)
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path))
@click.option("--k", default=4, show_default=True, type=int, help="Keypoints per mask.")
@friendly_errors
def heatmap_cmd(masks: tuple[str, ...], out_dir: Path, k: int) -> None:
    """Algorithm 1 on binary PNG masks (files or folders).

    Writes per mask <stem>_heatmap.npy (H×W×2 float32: heatmap, mask) and <stem>.json
    ({"keypoints": [[x, y], …], "rules": […]}); a mask named <stem>_mask.png gives <stem>.
    """
    import numpy as np

    from weldpool_core.errors import InvalidInputError
    from weldpool_core.heatmap import HeatmapParams, heatmap_from_mask
    from weldpool_core.io import read_mask

    params = HeatmapParams(k=k)
    paths = _input_masks(masks)
    out_dir.mkdir(parents=True, exist_ok=True)
    for path in paths:
        try:
            result = heatmap_from_mask(read_mask(path), params)
        except InvalidInputError as exc:
            raise InvalidInputError(f"{path}: {exc.message}") from None
        stem = _stem(path)
        np.save(out_dir / f"{stem}_heatmap.npy", result.heatmap)
        height, width = result.heatmap.shape[:2]
        record = {
            "keypoints": result.keypoints.tolist(),
            "rules": list(result.rules),
            "width": width,
            "height": height,
            "mask": str(path),
        }
        (out_dir / f"{stem}.json").write_text(json.dumps(record, indent=2) + "\n")
    click.echo(f"wrote {len(paths)} heatmap(s) to {out_dir}", err=True)


@main.group("eval")
def eval_group() -> None:
    """Score predictions against ground truth; JSON on stdout."""


@eval_group.command("segmentation")
@click.option("--pred", "pred_dir", required=True, type=click.Path(path_type=Path))
@click.option("--gt", "gt_dir", required=True, type=click.Path(path_type=Path))
@friendly_errors
def eval_segmentation(pred_dir: Path, gt_dir: Path) -> None:
    """IoU per frame, mIoU and quartiles (fractions in [0, 1]).

    Ground truth: <stem>.png in --gt (or its masks/). Prediction: <stem>_mask.png or <stem>.png
    in --pred (or its masks/). A missing prediction scores as an empty mask and is listed.
    """
    import numpy as np

    from weldpool_core.errors import InvalidInputError
    from weldpool_core.io import read_mask
    from weldpool_core.metrics import iou, segmentation_scores

    truth_dir, predicted_dir = _part(gt_dir, "masks"), _part(pred_dir, "masks")
    truths = {_stem(p): p for p in sorted(truth_dir.glob("*.png"))}
    if not truths:
        fail(f"{truth_dir} holds no ground-truth mask (<stem>.png).")
    per_image: dict[str, float] = {}
    missing: list[str] = []
    for stem, truth_path in truths.items():
        candidates = [predicted_dir / f"{stem}_mask.png", predicted_dir / f"{stem}.png"]
        found = next((c for c in candidates if c.is_file()), None)
        try:
            truth = read_mask(truth_path)
            predicted = read_mask(found) if found else np.zeros_like(truth)
            per_image[stem] = iou(predicted, truth)
        except InvalidInputError as exc:
            raise InvalidInputError(f"{stem}: {exc.message}") from None
        if found is None:
            missing.append(stem)
    if len(missing) == len(truths):
        fail(
            f"{predicted_dir} holds no prediction for the masks in {truth_dir} "
            "(expected <stem>_mask.png or <stem>.png)."
        )
    report = segmentation_scores(per_image).as_dict() | {"missing": missing}
    click.echo(json.dumps(report, indent=2))


def _keypoint_file(path: Path) -> list[Any]:
    from weldpool_core.errors import InvalidInputError

    try:
        keypoints = json.loads(path.read_text())["keypoints"]
        if not isinstance(keypoints, list):
            raise TypeError
    except (OSError, ValueError, KeyError, TypeError):
        raise InvalidInputError(
            f'{path} is not a keypoints file; expected {{"keypoints": [[x, y], …]}}.'
        ) from None
    return keypoints


@eval_group.command("keypoints")
@click.option("--pred", "pred_dir", required=True, type=click.Path(path_type=Path))
@click.option("--gt", "gt_dir", required=True, type=click.Path(path_type=Path))
@click.option(
    "--matching",
    type=click.Choice(["hungarian", "order"]),
    default="hungarian",
    show_default=True,
    help="Pair keypoints by least distance, or by position.",
)
@friendly_errors
def eval_keypoints(pred_dir: Path, gt_dir: Path, matching: str) -> None:
    """mED, mED_k and std in pixels, and the distances per frame.

    Ground truth: <stem>.json in --gt (or its keypoints/); prediction: <stem>.json in --pred. A
    missing prediction counts as empty: its keypoints are missed, and it is listed.
    """
    from weldpool_core.metrics import keypoint_scores

    truth_dir, predicted_dir = _part(gt_dir, "keypoints"), _part(pred_dir, "keypoints")
    truths = {p.stem: p for p in sorted(truth_dir.glob("*.json"))}
    if not truths:
        fail(f"{truth_dir} holds no ground-truth keypoints (<stem>.json).")
    pairs: dict[str, tuple[list[Any], list[Any]]] = {}
    missing: list[str] = []
    for stem, truth_path in truths.items():
        predicted_path = predicted_dir / f"{stem}.json"
        if not predicted_path.is_file():
            missing.append(stem)
        predicted = _keypoint_file(predicted_path) if predicted_path.is_file() else []
        pairs[stem] = (predicted, _keypoint_file(truth_path))
    if len(missing) == len(truths):
        fail(
            f"{predicted_dir} holds no prediction for the keypoints in {truth_dir} "
            "(expected <stem>.json)."
        )
    scores = keypoint_scores(pairs, matching="order" if matching == "order" else "hungarian")
    click.echo(json.dumps(scores.as_dict() | {"missing": missing}, indent=2))


PAPER_MIOU: dict[PromptName, float] = {"none": 35.37, "center": 34.82, "heuristic": 75.26}


@eval_group.command("teacher")
@click.option("--images", "images_dir", required=True, type=click.Path(path_type=Path))
@click.option("--masks", "masks_dir", required=True, type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="JSON on stdout instead of the table.")
@friendly_errors
def eval_teacher(images_dir: Path, masks_dir: Path, as_json: bool) -> None:
    """The paper's prompt ablation on a labelled folder: mIoU of none, center and heuristic.

    Images: <stem>.<png|jpg|tif|bmp> in --images (or its images/); ground truth: <stem>.png in
    --masks (or its masks/). DINO and SAM2 run once per frame; only the prompts differ.
    """
    import hashlib

    from app.teacher import runtime
    from weldpool_core.io import read_image, read_mask, to_rgb8
    from weldpool_core.metrics import iou, segmentation_scores
    from weldpool_core.teacher.prompt_names import DEFAULT_PROMPTS

    settings = load_settings()
    truth_dir = _part(masks_dir, "masks")
    files = [
        p
        for p in image_files((str(_part(images_dir, "images")),))
        if (truth_dir / f"{p.stem}.png").is_file()
    ]
    if not files:
        fail(f"No image in {images_dir} has a mask <stem>.png in {truth_dir}.")
    teacher = runtime.teacher(settings, DEFAULT_PROMPTS)
    per_config: dict[PromptName, dict[str, float]] = {name: {} for name in PAPER_MIOU}
    with click.progressbar(files, label="eval teacher", file=sys.stderr) as bar:
        for path in bar:
            data = path.read_bytes()
            image = to_rgb8(read_image(data, max_pixels=settings.max_image_pixels))
            truth = read_mask(truth_dir / f"{path.stem}.png")
            if truth.shape != image.shape[:2]:
                fail(
                    f"{path.stem}: the mask is {truth.shape[1]}×{truth.shape[0]}, the image "
                    f"{image.shape[1]}×{image.shape[0]}."
                )
            attention = teacher.dino(image)
            embedding = teacher.embedding(image, hashlib.sha256(data).hexdigest())
            for name, scores in per_config.items():
                scores[path.stem] = iou(teacher.propose(attention, embedding, name).mask, truth)
    report = {name: segmentation_scores(scores).as_dict() for name, scores in per_config.items()}
    if as_json:
        click.echo(json.dumps(report, indent=2))
        return
    click.echo(f"prompt ablation on {len(files)} frames (IoU in %)")
    click.echo(f"{'prompts':<10} {'mIoU':>7} {'Q1':>7} {'median':>7} {'Q3':>7} {'paper mIoU':>11}")
    for name, row in report.items():
        quartiles = row["quartiles"]
        click.echo(
            f"{name:<10} {100 * row['mIoU']:>7.2f} {100 * quartiles['q1']:>7.2f} "
            f"{100 * quartiles['median']:>7.2f} {100 * quartiles['q3']:>7.2f} "
            f"{PAPER_MIOU[name]:>11.2f}"
        )
