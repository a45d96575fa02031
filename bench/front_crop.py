"""A refinement pass on a crop around the pool's front, measured on the 15 real labels.

Issue 31 asks whether the mask at the wire (where the keypoint error sits: the two front corners)
gains from resolution at the front. The student sees a 1280×800 frame letterboxed to 256² (5
frame pixels a model pixel); a second student of the same settings, trained on a ``--crop``-pixel
square around each training frame's pool front (its rightmost extent, where the wire comes in,
at the height of the pool there), sees the front at ``--crop`` / 256 frame pixels a model pixel. At
test, the first student's mask places the crop; the second student's mask replaces the first's
inside it. Both are scored with Algorithm 1's keypoints on the full-resolution mask (the
default student reads its own from its mask at model resolution). Both students are trained
like ``bench/real_student.py``'s folds (the default settings, the best round chosen on the
training frames), on the same seeds.

    PYTHONPATH=bench:. .venv/bin/python bench/front_crop.py [--kinds within loco] [--seeds 0]
        [--crop 448] [--cache DIR]

Prints, per held-out frame and seed, mIoU and mED of the first student alone and with the
refinement, then a table per fold (means over its frames and the seeds).

The crop student's keypoints are Algorithm 1's on the cropped masks, whose back corners lie where
the crop cuts the pool: only its mask is used, but its encoder also learns those made-up corners.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from real_student import folds, real_frames
from results import recorded

from weldpool_core.errors import InvalidInputError
from weldpool_core.heatmap import HeatmapParams, keypoints_from_mask
from weldpool_core.metrics import iou, match_keypoints
from weldpool_core.student.data import TrainingFrame
from weldpool_core.student.model import StudentConfig
from weldpool_core.student.predict import StudentPredictor
from weldpool_core.student.train import TrainConfig, train_student


def front_box(mask: np.ndarray, crop: int) -> tuple[int, int, int, int] | None:
    """``(x0, y0, x1, y1)``: a ``crop``-pixel square reaching about a quarter of its side past the
    mask's rightmost pixel, centred on the rows the mask spans in the half-side nearest that
    pixel (moved inside the frame); None when the mask is empty."""
    ys, xs = np.nonzero(mask)
    if xs.size == 0:
        return None
    height, width = mask.shape
    right = int(xs.max())
    near = ys[xs >= right - crop // 2]
    centre_y = (int(near.min()) + int(near.max())) // 2
    x0 = min(max(right + crop // 4 - crop, 0), max(width - crop, 0))
    y0 = min(max(centre_y - crop // 2, 0), max(height - crop, 0))
    return x0, y0, min(x0 + crop, width), min(y0 + crop, height)


def cropped(frame: TrainingFrame, box: tuple[int, int, int, int]) -> TrainingFrame:
    x0, y0, x1, y1 = box
    image = np.ascontiguousarray(frame.image[y0:y1, x0:x1])
    return TrainingFrame(image, np.ascontiguousarray(frame.mask[y0:y1, x0:x1]), None, frame.name)


def scores(mask: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """IoU and the mean distance of Algorithm 1's keypoints on ``mask`` to those on ``truth``."""
    params = HeatmapParams(k=4)
    try:
        own = keypoints_from_mask(mask, params)
    except InvalidInputError:
        own = np.zeros((0, 2))
    distances = match_keypoints(own, keypoints_from_mask(truth, params))
    return iou(mask, truth), float(np.nanmean(np.where(np.isnan(distances), 1e3, distances)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kinds", nargs="+", default=["within", "loco"])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--crop", type=int, default=448, help="crop side, frame pixels")
    parser.add_argument("--cache", type=Path, help="keep trained folders here and reuse them")
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    frames = real_frames()
    student = StudentConfig()
    rows: list[tuple[str, int, float, float, float, float]] = []
    with tempfile.TemporaryDirectory() as scratch:
        root = args.cache or Path(scratch)
        for seed in args.seeds:
            config = replace(TrainConfig(device="cpu"), seed=seed)
            for kind in args.kinds:
                for name, train_ids, test_ids in folds(frames, kind):
                    train = [frames[i] for i in train_ids]
                    test = [frames[i] for i in test_ids]
                    slug = f"{name.replace(':', '-')}-s{seed}"
                    whole, front = root / f"whole-{slug}", root / f"front{args.crop}-{slug}"
                    crops = [
                        cropped(f, box) for f in train if (box := front_box(f.mask, args.crop))
                    ]
                    for folder, fold_frames in ((whole, train), (front, crops)):
                        if not (folder / "bench-done").is_file():
                            train_student(
                                fold_frames, folder, student, config, validation=fold_frames
                            )
                            (folder / "bench-done").write_text("")
                    first = StudentPredictor.load(whole, "cpu")
                    second = StudentPredictor.load(front, "cpu")
                    for frame, prediction in zip(
                        test, first.predict([f.image for f in test]), strict=True
                    ):
                        plain = scores(prediction.mask, frame.mask)
                        combined = prediction.mask.copy()
                        box = front_box(prediction.mask, args.crop)
                        if box is not None:
                            x0, y0, x1, y1 = box
                            crop_image = np.ascontiguousarray(frame.image[y0:y1, x0:x1])
                            combined[y0:y1, x0:x1] = second.predict([crop_image])[0].mask
                        refined = scores(combined, frame.mask)
                        rows.append((f"{name} {frame.name[-5:]}", seed, *plain, *refined))
                        print(
                            f"  {name} {frame.name} s{seed}: mIoU {plain[0]:.3f} → "
                            f"{refined[0]:.3f}, mED {plain[1]:.1f} → {refined[1]:.1f} px",
                            flush=True,
                        )
    print(
        f"\n| fold | frames × seeds | first: mIoU | mED px | with the {args.crop}² front crop: "
        "mIoU | mED px |"
    )
    print("|---|---:|---:|---:|---:|---:|")
    for group in sorted({r[0].split()[0] for r in rows}):
        mine = [r for r in rows if r[0].split()[0] == group]
        means = [statistics.mean(r[i] for r in mine) for i in (2, 3, 4, 5)]
        print(
            f"| {group} | {len(mine)} | {means[0]:.3f} | {means[1]:.1f} | {means[2]:.3f} "
            f"| {means[3]:.1f} |"
        )


if __name__ == "__main__":
    with recorded(__file__):
        main()
