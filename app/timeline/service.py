"""The timeline of a weld run: per frame, the pool's geometry from its reviewed label, else from
the proposal the policy shows (``weldpool_core.geometry`` computes it), with the frame's status
and the proposal's confidence.

Length and width are measured along one travel axis for the whole run, so that they compare
from frame to frame: the run's median of its masks' major axes (pools are longest along the
weld). Each mask file is decoded once per process: its shape (area, centroid, axis, hull) is
cached, and lengths along any axis come from the hull.
"""

from __future__ import annotations

import csv
import io
import math
import threading
from collections import OrderedDict
from typing import TYPE_CHECKING, Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from app.core.errors import MissingFile
from app.core.models import Frame, Label, LabelStatus, Proposal
from app.frames.schemas import stored_scale
from app.frames.sequences import get_sequence
from app.labelconfig import service as labelconfig
from app.proposals import policy
from app.storage import Storage
from app.storage.pixels import load_mask
from app.system.doctor import frame_file_missing
from app.timeline.classes import configured, frame_classes
from weldpool_core.geometry import PoolShape, pool_shape

if TYPE_CHECKING:
    import numpy as np
else:
    from weldpool_core.lazy import np

_CACHE_SIZE = 50_000
_cache_lock = threading.Lock()
_cache: OrderedDict[str, PoolShape] = OrderedDict()


def _shape(storage: Storage, mask_path: str) -> PoolShape | MissingFile:
    """A mask file's shape (area, centroid, axis, hull), decoded once per process; the
    MissingFile when the store lost it (its frame has no geometry, and says why)."""
    key = f"{storage.home}:{mask_path}"  # never a fetch: the shape may be cached
    with _cache_lock:
        if key in _cache:
            _cache.move_to_end(key)
            return _cache[key]
    try:
        shape = pool_shape(load_mask(storage, mask_path))
    except MissingFile as missing:
        return missing
    with _cache_lock:
        _cache[key] = shape
        while len(_cache) > _CACHE_SIZE:
            _cache.popitem(last=False)
    return shape


def _confidence(proposal: Proposal) -> float | None:
    """The proposal's own confidence: SAM2's predicted IoU (propagation: its per-frame score)."""
    scores = proposal.scores or {}
    value = scores.get("confidence", scores.get("sam2_iou"))
    return None if value is None else float(value)


Source = tuple[Frame, str | None, str | None, Proposal | None]
"""A frame, where its pool comes from (``label``, a proposal's source key, or None), that
mask's path, and the proposal it comes from."""


def _run_labels(session: Session, ids: list[int]) -> dict[int, Label]:
    labels: dict[int, Label] = {}
    for start in range(0, len(ids), 5000):  # bounded IN lists
        chunk = ids[start : start + 5000]
        labels.update(
            (label.frame_id, label)
            for label in session.scalars(sa.select(Label).where(Label.frame_id.in_(chunk)))
        )
    return labels


def _source(frame: Frame, label: Label | None, proposal: Proposal | None) -> Source:
    """A reviewed mask first (a rejected frame has no usable pool), else the proposal the
    policy shows."""
    if label is not None and label.status == LabelStatus.rejected:
        return frame, "label", None, None
    if label is not None and label.mask_path:
        return frame, "label", label.mask_path, None
    if proposal is not None:
        return frame, policy.source_key(proposal), proposal.mask_path, proposal
    return frame, None, None, None


def _row(source: Source, label: Label | None, geometry: Any, scale: float | None) -> dict[str, Any]:
    frame, key, _, proposal = source
    lost = None
    if isinstance(geometry, MissingFile):
        kind = "label mask" if key == "label" else "proposal mask"
        lost, geometry = frame_file_missing(geometry, frame.id, kind).message, None
    if key == "label" and label:
        keypoints = label.keypoints
    else:
        keypoints = proposal.keypoints if proposal else []
    row: dict[str, Any] = {
        "frame_id": frame.id,
        "frame_index": frame.frame_index,
        "timestamp_s": frame.timestamp_s,
        "status": frame.status.value,
        "source": key,
        "confidence": _confidence(proposal) if proposal is not None else None,
        "area_px": geometry.area_px if geometry else None,
        "length_px": geometry.length_px if geometry else None,
        "width_px": geometry.width_px if geometry else None,
        "centroid": list(geometry.centroid) if geometry and geometry.centroid else None,
        "keypoints": keypoints or [],
        "missing_file": lost,
    }
    none = {"area_mm2": None, "length_mm": None, "width_mm": None}
    return row | (geometry.in_mm(scale) if geometry else none) | frame_classes(label, scale)


def sequence_geometry(session: Session, storage: Storage, sequence_id: int) -> dict[str, Any]:
    """Every frame of the run in frame order, with its geometry, source and confidence, and
    its label's other classes and tags (``app.timeline.classes``)."""
    sequence = get_sequence(session, sequence_id)
    frames = list(
        session.scalars(
            sa.select(Frame)
            .where(Frame.sequence_id == sequence_id)
            .order_by(Frame.frame_index.is_(None), Frame.frame_index, Frame.id)
        )
    )
    ids = [f.id for f in frames]
    labels = _run_labels(session, ids)
    proposals = policy.pick_many(session, storage, ids)
    sources = [_source(f, labels.get(f.id), proposals.get(f.id)) for f in frames]
    scale = stored_scale(sequence.mm_per_px)  # one outside the physical range: no mm at all
    shapes = {path: _shape(storage, path) for _, _, path, _ in sources if path is not None}
    measured = [s for s in shapes.values() if isinstance(s, PoolShape)]
    travel = _median_axis([s.major_deg for s in measured if s.major_deg is not None])
    rows = [
        _row(source, labels.get(source[0].id), _measured(shapes, source[2], travel), scale)
        for source in sources
    ]
    return {
        "sequence_id": sequence.id,
        "name": sequence.name,
        "mm_per_px": scale,
        "travel_deg": travel,
        "travel_source": "the run's median major axis of its masks" if travel is not None else None,
        "process": {
            "wire_feed_m_min": sequence.wire_feed_m_min,
            "voltage_v": sequence.voltage_v,
            "current_a": sequence.current_a,
            "arc_length_correction_pct": sequence.arc_length_correction_pct,
            "robot_speed_cm_min": sequence.robot_speed_cm_min,
            "synergic_law": sequence.synergic_law,
            "joint_type": sequence.joint_type,
        },
        "frames": rows,
    } | configured(labelconfig.current(session))


def _measured(shapes: dict[str, Any], path: str | None, travel: float | None) -> Any:
    """The frame's geometry along the travel axis; its MissingFile when its mask is lost."""
    if path is None:
        return None
    shape = shapes[path]
    return shape.measure(travel) if isinstance(shape, PoolShape) else shape


def _median_axis(degrees: list[float]) -> float | None:
    """The median of undirected axes (mod 180°), taken around their circular mean."""
    if not degrees:
        return None
    doubled = np.radians(np.asarray(degrees) * 2.0)
    centre = math.degrees(math.atan2(np.sin(doubled).mean(), np.cos(doubled).mean())) / 2.0
    offsets = (np.asarray(degrees) - centre + 90.0) % 180.0 - 90.0
    return float((centre + float(np.median(offsets))) % 180.0)


CSV_COLUMNS = (
    "frame_id",
    "frame_index",
    "timestamp_s",
    "status",
    "source",
    "confidence",
    "area_px",
    "length_px",
    "width_px",
    "centroid_x",
    "centroid_y",
    "area_mm2",
    "length_mm",
    "width_mm",
)


def geometry_csv(timeline: dict[str, Any]) -> str:
    """The timeline as CSV: one row per frame; its tags (``;`` between them) and each other
    class's objects and summed area (``<class> objects``, ``<class> area_px``; empty without a
    label); keypoints as k1_x, k1_y, … at the end."""
    k = max((len(row["keypoints"]) for row in timeline["frames"]), default=0)
    names = [c["name"] for c in timeline.get("classes", [])]
    out = io.StringIO()
    writer = csv.writer(out)
    writer.writerow(
        [
            *CSV_COLUMNS,
            "tags",
            *(f"{name} {what}" for name in names for what in ("objects", "area_px")),
            *(f"k{i + 1}_{axis}" for i in range(k) for axis in "xy"),
        ]
    )
    for row in timeline["frames"]:
        centroid = row["centroid"] or [None, None]
        flat = {**row, "centroid_x": centroid[0], "centroid_y": centroid[1]}
        points = [v for point in row["keypoints"] for v in point]
        points += [None] * (2 * k - len(points))
        labelled = row["source"] == "label"
        held = [
            _cell(v)
            for name in names
            for v in (
                (row["classes"].get(name) or {}).get("count", 0) if labelled else None,
                (row["classes"].get(name) or {}).get("area_px"),
            )
        ]
        writer.writerow(
            [_cell(flat[c]) for c in CSV_COLUMNS]
            + [";".join(row.get("tags", []))]
            + held
            + [_cell(v) for v in points]
        )
    return out.getvalue()


def _cell(value: Any) -> Any:
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:.4f}".rstrip("0").rstrip(".")
    return value
