"""What the service can do right now, in words: the one place health, pages and buttons ask."""

from __future__ import annotations

from app.config import Settings
from weldpool_core.teacher.weights import weights_status


def teacher_problem(settings: Settings) -> str | None:
    """Why the teacher cannot run here (missing weights), in one sentence; None when it can."""
    missing = [
        status
        for status in (
            weights_status(settings.dino, "WELDPOOL_DINO"),
            weights_status(settings.sam2, "WELDPOOL_SAM2"),
        )
        if not status.available
    ]
    if not missing:
        return None
    names = " and ".join(s.setting for s in missing)
    return (
        f"The teacher cannot run: its weights are missing ({names}). Run `weldpool weights "
        "fetch` on a machine with internet access, or point "
        f"{names} at a local folder, then restart."
    )
