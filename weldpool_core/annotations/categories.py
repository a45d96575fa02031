"""Which of a file's categories is the weld pool: the one rule every reader applies."""

from __future__ import annotations

from collections.abc import Iterable

POOL_NAMES = frozenset(
    {
        "weld_pool",
        "weld pool",
        "weldpool",
        "pool",
        "melt_pool",
        "melt pool",
        "meltpool",
        "molten_pool",
        "molten pool",
    }
)
"""Category names taken for the pool without being told (compared case-insensitively)."""


def pool_names(names: Iterable[str], wanted: str | None = None) -> set[str]:
    """The names among ``names`` that mean the pool: ``wanted`` when given; else the known pool
    names; else, when the file has exactly one category, that one."""
    distinct = {n for n in names if isinstance(n, str)}
    if wanted:
        return {n for n in distinct if n.casefold() == wanted.casefold()}
    known = {n for n in distinct if n.strip().casefold() in POOL_NAMES}
    if known:
        return known
    return distinct if len(distinct) == 1 else set()
