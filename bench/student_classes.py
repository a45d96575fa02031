"""The student on the real WAAM labels with an extra class beside the pool: does the pool lose?

The real labels hold the pool alone (15 hand-drawn masks, 5 a clip), so the extra classes are
built from them, real-ish and reproducible:

- ``bright core`` (a mask class): the brightest quarter of the pool's pixels (grey level at or
  above the pool's 75th percentile), opened by a 5×5 ellipse, the largest part kept;
- ``pool tip`` (a points class, one point ``tip``): the pool's rightmost mask pixel (mean row
  of its rightmost column), the front of the pool in these clips' frames.

Each fold (leave-one-clip-out, and within-clip: train on four frames of a clip, test on its
f0250; ``real_student.folds``) trains a student twice from the same seed, without and with
the two classes, and scores the held-out frames: the pool's mIoU and mED (as
``bench/real_student.py``), and the classes' figures (``student.classes.class_figures``: IoU,
distance in px). Everything but the classes is the same, and a student with classes starts its
pool from the same initial weights (the class head is made last).

Settings kept small for a shared 2-core machine (say so with the figures): ``--steps`` (default
300 instead of the library's 800), 10 evaluation rounds, no uncertainty draws; ``--folds N``
runs only the first N folds of each kind, and ``--from-logs`` makes the tables from the rows of
runs split across processes.

    PYTHONPATH=. .venv/bin/python bench/student_classes.py [--steps 300] [--kinds loco within]
        [--folds 1] [--from-logs LOG …]
"""

from __future__ import annotations

import argparse
import ast
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
from real_student import folds, real_frames
from results import Table, record

from weldpool_core.student.classes import ClassTruth, LearnedClass, class_figures
from weldpool_core.student.data import TrainingFrame
from weldpool_core.student.evaluate import train_and_score
from weldpool_core.student.model import StudentConfig
from weldpool_core.student.train import TrainConfig

CLASSES = (LearnedClass("bright core", "mask"), LearnedClass("pool tip", "points", ("tip",)))


def bright_core(frame: TrainingFrame) -> np.ndarray:
    """The brightest quarter of the pool, opened, its largest part (see the module doc)."""
    grey = cv2.cvtColor(frame.image, cv2.COLOR_RGB2GRAY)
    inside = grey[frame.mask]
    core = frame.mask & (grey >= np.percentile(inside, 75))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
    core = cv2.morphologyEx(core.astype(np.uint8), cv2.MORPH_OPEN, kernel)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(core)
    if count <= 1:
        return frame.mask.copy()
    largest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    return np.asarray(labels == largest)


def pool_tip(frame: TrainingFrame) -> tuple[float, float]:
    """The pool's rightmost pixel column, at its mean row."""
    rows, columns = np.nonzero(frame.mask)
    right = columns.max()
    return float(right), float(rows[columns == right].mean())


def with_classes(frame: TrainingFrame) -> TrainingFrame:
    truths = {
        "bright core": ClassTruth(mask=bright_core(frame)),
        "pool tip": ClassTruth(points={"tip": pool_tip(frame)}),
    }
    return replace(frame, classes=truths)


def run(args: argparse.Namespace) -> list[dict[str, Any]]:
    frames = [with_classes(f) for f in real_frames()]
    config = TrainConfig(device="cpu", steps=args.steps, rounds=args.rounds, seed=args.seed)
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        for kind in args.kinds:
            for name, train, test in folds(frames, kind)[: args.folds]:
                for label, classes in (("pool only", ()), ("pool + 2 classes", CLASSES)):
                    student = StudentConfig(input_size=args.input_size, classes=classes)
                    folder = Path(scratch) / f"{name.replace(':', '-')}-{len(classes)}"
                    held = [frames[i] for i in test]
                    fold = train_and_score(
                        [frames[i] for i in train], held, folder, student, config, samples=0
                    )
                    figures = class_figures(
                        classes,
                        [p.classes for p in fold.predictions],
                        [f.classes for f in held],
                        [f.mask.shape for f in held],
                    )
                    row = {
                        "kind": kind,
                        "fold": name,
                        "student": label,
                        "mIoU": fold.scores.miou,
                        "mED": fold.scores.med,
                        "core IoU": figures.get("bright core", {}).get("IoU"),
                        "tip px": figures.get("pool tip", {}).get("distance_px"),
                        "seconds": fold.seconds,
                    }
                    print(row, flush=True)
                    rows.append(row)
    return rows


def logged_rows(logs: list[Path]) -> list[dict[str, Any]]:
    """The rows earlier runs printed (one dict a line), in the order of the logs."""
    rows = []
    for log in logs:
        for line in log.read_text().splitlines():
            if line.startswith("{'kind'"):
                rows.append(ast.literal_eval(line))
    return rows


def _fmt(value: Any, digits: int) -> str:
    return "–" if value is None else f"{value:.{digits}f}"


def tables(rows: list[dict[str, Any]]) -> list[Table]:
    per_fold = Table(
        "pool and classes per held-out fold",
        ["fold", "student", "pool mIoU", "pool mED px", "core IoU", "tip px", "train s"],
        [
            [
                r["fold"],
                r["student"],
                _fmt(r["mIoU"], 3),
                _fmt(r["mED"], 1),
                _fmt(r["core IoU"], 3),
                _fmt(r["tip px"], 1),
                _fmt(r["seconds"], 0),
            ]
            for r in rows
        ],
    )
    means = []
    for kind in dict.fromkeys(r["kind"] for r in rows):
        for label in ("pool only", "pool + 2 classes"):
            mine = [r for r in rows if r["kind"] == kind and r["student"] == label]
            core = [r["core IoU"] for r in mine if r["core IoU"] is not None]
            tip = [r["tip px"] for r in mine if r["tip px"] is not None]
            means.append(
                [
                    "across clips (LOCO)" if kind == "loco" else "within clip",
                    label,
                    _fmt(float(np.mean([r["mIoU"] for r in mine])), 3),
                    _fmt(float(np.mean([r["mED"] for r in mine if r["mED"] is not None])), 1),
                    _fmt(float(np.mean(core)) if core else None, 3),
                    _fmt(float(np.mean(tip)) if tip else None, 1),
                ]
            )
    mean = Table(
        "pool with and without extra classes (mean of the folds)",
        ["folds", "student", "pool mIoU", "pool mED px", "core IoU", "tip px"],
        means,
    )
    return [mean, per_fold]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=300, help="optimiser steps per training")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument(
        "--kinds", nargs="+", default=["loco", "within"], choices=["loco", "within"]
    )
    parser.add_argument("--folds", type=int, help="the first N folds of each kind only")
    parser.add_argument("--rounds", type=int, default=10, help="evaluation rounds per training")
    parser.add_argument("--input-size", type=int, default=256, help="the student's input side")
    parser.add_argument(
        "--from-logs",
        nargs="+",
        type=Path,
        help="no training: the tables of the rows earlier runs printed (runs split by fold)",
    )
    parser.add_argument("--no-record", action="store_true", help="print only")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    started = time.perf_counter()
    found = tables(logged_rows(args.from_logs) if args.from_logs else run(args))
    for table in found:
        print(table.markdown())
    print(
        f"{time.perf_counter() - started:.0f} s in all (steps {args.steps}, {args.rounds} "
        f"rounds, input {args.input_size})"
    )
    if not args.no_record:
        command = f"PYTHONPATH=. .venv/bin/python bench/student_classes.py --steps {args.steps}"
        command += f" --rounds {args.rounds} --input-size {args.input_size}"
        command += f" --folds {args.folds}" if args.folds else ""
        print(f"written to {record('bench/student_classes.py', found, command)}")


if __name__ == "__main__":
    main()
