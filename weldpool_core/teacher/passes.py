"""Which frames a propagation walks, in which order: plain index arithmetic, importable without
torch (the web process checks a request with it; ``propagate`` runs it)."""

from __future__ import annotations

from typing import Any, Literal

Direction = Literal["forward", "backward", "both"]


def passes(
    count: int, prompts: dict[int, Any], direction: Direction, until: int | None = None
) -> list[tuple[range, bool]]:
    """The frame positions each pass walks, and whether it runs backward: forward from the
    first prompt to ``until`` (or the end), backward from the first prompt (both directions) or
    the last one (backward only) to ``until`` (or the start). Prompted frames are in the ranges
    and get no mask of their own."""
    first, last = min(prompts), max(prompts)
    out: list[tuple[range, bool]] = []
    if direction in ("forward", "both"):
        end = count - 1 if until is None or direction == "both" else min(until, count - 1)
        out.append((range(first, end + 1), False))
    if direction in ("backward", "both"):
        end = 0 if until is None or direction == "both" else max(until, 0)
        out.append((range(first if direction == "both" else last, end - 1, -1), True))
    return out
