"""Per-class figures of the labels (``LabelFacet`` rows, written with each label): for each
class, the frames whose label holds it, its objects and the frames among them whose label is
approved (the review stage off: every saved label); for each frame tag, the frames tagged."""

from __future__ import annotations

import csv
import io
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from app.core.models import Label, LabelFacet, ReviewState
from app.labelconfig import service as labelconfig
from app.labelconfig.facets import CLASS, TAG


def class_figures(session: Session) -> dict[str, Any]:
    """``classes``: [{name, kind, frames, objects, reviewed, configured}] (the configured ones
    in their order, then any whose objects labels still hold though the configuration dropped
    it); ``tags``: [{name, frames, configured}]."""
    approved = sa.or_(Label.review.is_(None), Label.review == ReviewState.approved)
    rows = session.execute(
        sa.select(
            LabelFacet.kind,
            LabelFacet.key,
            sa.func.count(),
            sa.func.coalesce(sa.func.sum(LabelFacet.count), 0),
            sa.func.count(Label.id).filter(approved),
        )
        .join(Label, Label.frame_id == LabelFacet.frame_id)
        .where(LabelFacet.kind.in_([CLASS, TAG]))
        .group_by(LabelFacet.kind, LabelFacet.key)
    ).all()
    found = {(kind, key): (int(f), int(o), int(r)) for kind, key, f, o, r in rows}
    config = labelconfig.current(session).config
    kinds = {c["name"]: c["kind"] for c in config["classes"]}
    names = list(kinds) + sorted(k for kind, k in found if kind == CLASS and k not in kinds)
    classes = []
    for name in names:
        frames, objects, reviewed = found.get((CLASS, name), (0, 0, 0))
        classes.append(
            {
                "name": name,
                "kind": kinds.get(name),
                "frames": frames,
                "objects": objects,
                "reviewed": reviewed,
                "configured": name in kinds,
            }
        )
    tags = list(config.get("frame_tags", []))
    tags += sorted(k for kind, k in found if kind == TAG and k not in tags)
    configured = set(config.get("frame_tags", []))
    return {
        "classes": classes,
        "tags": [
            {"name": t, "frames": found.get((TAG, t), (0, 0, 0))[0], "configured": t in configured}
            for t in tags
        ],
    }


def classes_csv(figures: dict[str, Any]) -> str:
    """The figures as CSV: one row per class, then per tag (``what``: class or tag)."""
    out = io.StringIO()
    writer = csv.writer(out)
    writer.writerow(["what", "name", "kind", "frames", "objects", "reviewed", "configured"])
    for c in figures["classes"]:
        row = [c["kind"] or "", c["frames"], c["objects"], c["reviewed"], c["configured"]]
        writer.writerow([CLASS, c["name"], *row])
    for t in figures["tags"]:
        writer.writerow([TAG, t["name"], "", t["frames"], "", "", t["configured"]])
    return out.getvalue()
