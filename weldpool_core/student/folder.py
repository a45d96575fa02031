"""Training from a DATASET folder, with the other classes it labels beside the pool.

The layout is the one ``weldpool export --format masks`` writes, so that an unzipped export
trains as it is:

- ``classes/<class>/<stem>.png``: a ``mask`` class's mask of the frame ``<stem>`` (a PNG,
  nonzero = the class), ``classes/<class>/<stem>_<n>.png`` an ``instances`` class's n-th
  instance (the student learns their union); ``/`` and ``\\`` in a class name are ``_`` in its
  folder's name;
- ``manifest.json``: ``frames[].objects[]`` holds a ``points`` class's named points,
  ``{"class": <class>, "points": {<point>: [x, y]}}`` on the frame ``frames[].stem``, and
  ``classes`` declares each class's kind (and a points class's ``point_names``); without that
  declaration a class is ``points`` where it has points, ``instances`` where a file is numbered,
  else ``mask``, and a points class's points are the names its labels use (sorted).

A frame without a file or points of a class does not teach that class (``student.classes``).
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from weldpool_core.errors import InvalidInputError
from weldpool_core.io import read_mask
from weldpool_core.student import checkpoint
from weldpool_core.student.classes import ClassTruth, LearnedClass
from weldpool_core.student.data import IMAGE_SUFFIXES, TrainingFrame, read_dataset
from weldpool_core.student.model import StudentConfig

if TYPE_CHECKING:
    from weldpool_core.student.train import ProgressCallback, TrainConfig, TrainResult

CLASSES = "classes"
MANIFEST = "manifest.json"
NUMBERED = re.compile(r"^(?P<stem>.+)_(?P<n>[0-9]+)$")


def class_folder(name: str) -> str:
    """A class's folder name under ``classes/`` (as the masks export names it)."""
    return name.replace("/", "_").replace("\\", "_")


@dataclass
class _Found:
    """What a DATASET holds of one class: its mask files by stem (numbered: instances), its
    points by stem."""

    files: dict[str, list[Path]] = field(default_factory=dict)
    numbered: bool = False
    points: dict[str, dict[str, tuple[float, float]]] = field(default_factory=dict)


def _manifest(root: Path) -> dict[str, Any]:
    path = root / MANIFEST
    if not path.is_file():
        return {}
    try:
        manifest = json.loads(path.read_text())
        if not isinstance(manifest, dict):
            raise ValueError
    except (OSError, ValueError):
        raise InvalidInputError(
            f"{path} is not a masks export's manifest; expected a JSON object with frames."
        ) from None
    return manifest


def _points(path: Path, stem: str, name: str, points: Any) -> dict[str, tuple[float, float]]:
    try:
        read = {str(k): (float(xy[0]), float(xy[1])) for k, xy in points.items() if len(xy) == 2}
        if len(read) != len(points) or not all(map(_finite, read.values())):
            raise ValueError
    except (AttributeError, TypeError, ValueError, IndexError, KeyError):
        raise InvalidInputError(
            f"{path}: the {name!r} points of {stem!r} are not "
            '{"<point>": [x, y], …} with finite numbers.'
        ) from None
    return read


def _finite(xy: tuple[float, float]) -> bool:
    return all(abs(v) < float("inf") for v in xy)


def _manifest_points(root: Path, manifest: dict[str, Any], names: Sequence[str]) -> dict[str, Any]:
    """The points of each of ``names`` in the manifest, by stem."""
    found: dict[str, dict[str, dict[str, tuple[float, float]]]] = {n: {} for n in names}
    path = root / MANIFEST
    for frame in manifest.get("frames") or []:
        for obj in (frame.get("objects") or []) if isinstance(frame, dict) else []:
            name = obj.get("class") if isinstance(obj, dict) else None
            if name in found and obj.get("points") is not None:
                stem = str(frame.get("stem"))
                points = _points(path, stem, name, obj["points"])
                held = found[name].setdefault(stem, {})
                for point, xy in points.items():  # the first object's, as the app's truths
                    held.setdefault(point, xy)
    return found


def _pointed(manifest: dict[str, Any]) -> set[str]:
    """The classes with points in the manifest's frames."""
    return {
        str(obj.get("class"))
        for frame in manifest.get("frames") or []
        if isinstance(frame, dict)
        for obj in frame.get("objects") or []
        if isinstance(obj, dict) and obj.get("points") is not None
    }


def _files(root: Path, name: str, stems: set[str]) -> _Found:
    """The class's mask files by the stem of the image they belong to."""
    found = _Found()
    for path in sorted((root / CLASSES / class_folder(name)).glob("*.png")):
        if path.stem in stems:
            found.files.setdefault(path.stem, []).append(path)
        elif (match := NUMBERED.match(path.stem)) and match["stem"] in stems:
            found.files.setdefault(match["stem"], []).append(path)
            found.numbered = True
        else:
            raise InvalidInputError(
                f"{path} belongs to no image of the DATASET; name it <stem>.png (a mask class) "
                "or <stem>_<n>.png (an instance) after images/<stem>.*."
            )
    return found


def _learned(name: str, found: _Found, declared: Mapping[str, Any]) -> LearnedClass:
    spec = declared.get(name) or {}
    if found.files and found.points:
        raise InvalidInputError(
            f"The class {name!r} has both masks (classes/{class_folder(name)}/) and points "
            "(manifest.json); keep one kind per class."
        )
    if found.points:
        used = {point for held in found.points.values() for point in held}
        points = tuple(spec.get("point_names") or sorted(used))
        return LearnedClass(name, "points", points)
    kind = spec.get("kind") if spec.get("kind") in ("mask", "instances") else None
    return LearnedClass(name, kind or ("instances" if found.numbered else "mask"))


def read_classes(
    folder: str | Path, names: Sequence[str]
) -> tuple[tuple[LearnedClass, ...], Iterator[TrainingFrame]]:
    """The DATASET's classes ``names`` (module doc) and its frames, read one at a time, each with
    its labels of them. Raises InvalidInputError for a class the DATASET does not hold, a class
    with both masks and points, or a malformed file (named)."""
    root = Path(folder)
    manifest = _manifest(root)
    declared = {str(c.get("name")): c for c in manifest.get("classes") or [] if isinstance(c, dict)}
    stems = {p.stem for p in (root / "images").glob("*") if p.suffix.lower() in IMAGE_SUFFIXES}
    points = _manifest_points(root, manifest, names)
    found: dict[str, _Found] = {}
    for name in names:
        found[name] = _files(root, name, stems)
        found[name].points = points[name]
        if not found[name].files and not found[name].points:
            held = {p.name for p in (root / CLASSES).glob("*") if p.is_dir()}
            held |= {n for n, c in declared.items() if c.get("kind") == "points"}
            held |= _pointed(manifest)
            raise InvalidInputError(
                f"{root} holds no class {name!r} (classes/<class>/<stem>.png or points in "
                f"manifest.json); it holds {', '.join(sorted(held)) or 'none'}."
            )
    learned = tuple(_learned(name, found[name], declared) for name in names)
    return learned, _with_classes(read_dataset(root), learned, found)


def _with_classes(
    frames: Iterator[TrainingFrame], learned: tuple[LearnedClass, ...], found: dict[str, _Found]
) -> Iterator[TrainingFrame]:
    for frame in frames:
        truths: dict[str, ClassTruth] = {}
        for learned_class in learned:
            held = found[learned_class.name]
            if learned_class.kind == "points":
                if frame.name in held.points:
                    truths[learned_class.name] = ClassTruth(points=held.points[frame.name])
            elif frame.name in held.files:
                truths[learned_class.name] = ClassTruth(mask=_union(held.files[frame.name], frame))
        yield replace(frame, classes=truths)


def _union(paths: list[Path], frame: TrainingFrame) -> Any:
    union = None
    for path in paths:
        try:
            mask = read_mask(path)
        except (OSError, InvalidInputError) as exc:
            raise InvalidInputError(f"{path}: {getattr(exc, 'message', exc)}") from None
        if mask.shape != frame.mask.shape:
            raise InvalidInputError(
                f"{path} is {mask.shape[1]}×{mask.shape[0]} but its image "
                f"{frame.mask.shape[1]}×{frame.mask.shape[0]}; they must match."
            )
        union = mask if union is None else union | mask
    return union


def train_from_folder(
    dataset: str | Path,
    out_dir: str | Path,
    student: StudentConfig | None = None,
    config: TrainConfig | None = None,
    progress: ProgressCallback | None = None,
    resume: bool = False,
    classes: Sequence[str] = (),
) -> TrainResult:
    """``train_student`` on a DATASET folder, frames read one at a time, learning its
    ``classes`` beside the pool (``read_classes``; resumed: those the run learns, unless
    given, when they must be the same)."""
    from weldpool_core.student.train import train_student

    saved = Path(out_dir) / checkpoint.CONFIG_FILE
    if resume and not classes and saved.is_file():
        classes = [c.name for c in checkpoint.read_student_config(out_dir).classes]
    if not classes:
        frames: Iterator[TrainingFrame] = read_dataset(dataset)
        return train_student(frames, out_dir, student, config, progress, resume=resume)
    learned, frames = read_classes(dataset, classes)
    if student is None and resume and saved.is_file():
        student = replace(checkpoint.read_student_config(out_dir), classes=learned)
    student = replace(student or StudentConfig(), classes=learned)
    return train_student(frames, out_dir, student, config, progress, resume=resume)
