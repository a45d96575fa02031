"""Benchmark the frame lists at scale: the first and the last page of each list order.

Run: ``.venv/bin/python bench/scale.py [--frames 2000] [--database sqlite|postgresql]``
(``--frames 50000`` for a long weld run; PostgreSQL from ``WELDPOOL_TEST_POSTGRES_URL`` or the
local default, in a schema of its own that is dropped afterwards).

It fills one weld run with N scored frames as ingest and the teacher leave them (status, split,
uncertainty with its components, a 384-float DINO descriptor; no image files: lists never read
them; a label's facets on the accepted frames: the pool on each, a wire on one in ten), then
times ``GET /api/v1/frames`` in process (the app's whole request path, authentication
included) for the first page and the last page of each order, and the bare SQL of the same page
(the ids only, the floor), and the server's part without HTTP (the list and its JSON). Median
of several runs, milliseconds, and the process's RSS.
"""

from __future__ import annotations

import argparse
import functools
import os
import random
import statistics
import tempfile
import time
import uuid
from pathlib import Path
from typing import Any

import sqlalchemy as sa
from fastapi.testclient import TestClient
from results import recorded

from app.core.config import Settings
from app.core.db import create_db_engine, create_session_factory
from app.core.models import (
    UNREVIEWED_SQL,
    Frame,
    FrameStatus,
    LabelConfig,
    LabelFacet,
    Role,
    Sequence,
    Split,
    User,
)
from app.core.schema import migrate
from app.core.security import hash_password, issue_token
from app.frames import listing
from app.frames.schemas import FrameOut, FramePage
from app.labelconfig import service as labelconfig
from app.labelconfig.facets import filter_conditions
from app.labelconfig.service import Current
from app.main import create_app

PAGE = 50
# (order, status, class): the plain list by id, by frame index, the queue (frames still to
# review), the uncertainty order of every frame (the home page's default list), and the frames
# whose label holds a class (a wire: 2 % of the run; the pool: 20 %)
LISTS: tuple[tuple[str, str, str | None], ...] = (
    ("id", "all", None),
    ("frame_index", "all", None),
    ("uncertainty", "unreviewed", None),
    ("uncertainty", "all", None),
    ("id", "all", "wire"),
    ("id", "all", "pool"),
    ("uncertainty", "all", "wire"),
)
CONFIG = {"classes": [{"name": "pool", "kind": "mask"}, {"name": "wire", "kind": "mask"}]}
POSTGRES = os.environ.get(
    "WELDPOOL_TEST_POSTGRES_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/test"
)


def fill(session_factory: Any, count: int) -> tuple[int, str]:
    """One weld run of ``count`` scored frames; returns its id and an admin token."""
    rng = random.Random(0)
    with session_factory() as session:
        user = User(username="bench", password_hash=hash_password("bench-bench"), role=Role.admin)
        session.add(user)
        run = Sequence(name="long run")
        session.add(run)
        session.flush()
        _, token = issue_token(session, user, "bench")
        rows = []
        for index in range(count):
            scored = rng.random() < 0.9
            rows.append(
                {
                    "sequence_id": run.id,
                    "sha256": uuid.uuid4().hex + uuid.uuid4().hex,
                    "path": f"frames/x/{index}.png",
                    "original_name": f"f{index:06d}.png",
                    "media_type": "image/png",
                    "size_bytes": 300_000,
                    "width": 1280,
                    "height": 800,
                    "channels": 3,
                    "frame_index": index,
                    "timestamp_s": index / 15,
                    "split": Split.validation if index % 10 == 0 else Split.train,
                    "status": FrameStatus.proposed if rng.random() < 0.8 else FrameStatus.accepted,
                    "uncertainty": rng.random() if scored else None,
                    "uncertainty_components": {"sam2_doubt": rng.random(), "instability": 0.1}
                    if scored
                    else None,
                    "uncertainty_reason": "sam2_doubt" if scored else None,
                    "descriptor": [round(rng.random(), 5) for _ in range(384)],
                }
            )
        for start in range(0, len(rows), 1000):
            session.execute(sa.insert(Frame), rows[start : start + 1000])
        session.add(LabelConfig(version=1, config=CONFIG, user_id=user.id))
        accepted = session.scalars(
            sa.select(Frame.id).where(Frame.status == FrameStatus.accepted).order_by(Frame.id)
        ).all()
        facets = [{"frame_id": i, "kind": "class", "key": "pool", "value": ""} for i in accepted]
        facets += [
            {"frame_id": i, "kind": "class", "key": "wire", "value": ""} for i in accepted[::10]
        ]
        for start in range(0, len(facets), 1000):
            session.execute(sa.insert(LabelFacet), facets[start : start + 1000])
        session.commit()
        return run.id, token


def held(name: str | None) -> list[Any]:
    """The list's conditions on a class its labels hold."""
    return filter_conditions(Current(1, CONFIG), [name]) if name else []


def page_json(
    app: Any,
    run_id: int,
    order: str,
    status: str,
    offset: int,
    after: str | None = None,
    name: str | None = None,
) -> str:
    """What the route does for a page, without HTTP: the list, its rows as JSON (with a class
    filter, the configuration read as the route reads it)."""
    settings = app.state.settings
    with app.state.session_factory() as session:
        if name:
            labelconfig.current(session)
        page = listing.list_frames(
            session,
            sequence_id=run_id,
            status=None if status == "all" else "unreviewed",
            order=order,
            limit=PAGE,
            offset=0 if after else offset,
            after=after,
            diversity=settings.queue_diversity,
            diversity_pool=settings.queue_diversity_pool,
            facets=held(name),
        )
        return FramePage(
            items=[FrameOut.model_validate(r) for r in page.rows],
            total=page.total,
            limit=PAGE,
            offset=offset,
            next_after=page.next_after,
        ).model_dump_json()


def cursor_before(
    app: Any, run_id: int, order: str, status: str, offset: int, name: str | None
) -> str:
    """The cursor whose next page starts at ``offset`` (the previous row's sort key)."""
    with app.state.session_factory() as session:
        ordered, _ = listing.list_query(
            sequence_id=run_id,
            status=None if status == "all" else "unreviewed",
            order=order,
            facets=held(name),
        )
        row = session.scalars(ordered.offset(offset - 1).limit(1)).one()
        return listing.cursor_after(row, order)


def median_ms(call: Any, runs: int) -> float:
    call()
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return 1000 * statistics.median(times)


def paired_ratio(call: Any, plain: Any, runs: int) -> float:
    """The median over ``runs`` of ``call``'s time over ``plain``'s, timed back to back: a
    loaded machine's swings hit both alike."""
    ratios = []
    for _ in range(runs):
        start = time.perf_counter()
        plain()
        middle = time.perf_counter()
        call()
        ratios.append((time.perf_counter() - middle) / (middle - start))
    return statistics.median(ratios)


def rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def reverse_indexes(engine: Any) -> None:
    """The frames table's indexes dropped and made again in the reverse order of their names."""
    with engine.begin() as connection:
        rows = connection.exec_driver_sql(
            "SELECT name, sql FROM sqlite_master WHERE type = 'index' AND tbl_name = 'frames' "
            "AND sql IS NOT NULL ORDER BY name DESC"
        ).all()
        for name, _ in rows:
            connection.exec_driver_sql(f"DROP INDEX {name}")
        for _, sql in rows:
            connection.exec_driver_sql(sql)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=2000)
    parser.add_argument("--database", choices=["sqlite", "postgresql"], default="sqlite")
    parser.add_argument("--runs", type=int, default=7)
    parser.add_argument(
        "--reverse-indexes",
        action="store_true",
        help="make the frames table's indexes again in the reverse order (SQLite): the plans "
        "must not change",
    )
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as home:
        if args.database == "sqlite":
            url = f"sqlite:///{home}/weldpool.sqlite3"
        else:
            schema = f"wp_bench_{uuid.uuid4().hex[:8]}"
            url = f"{POSTGRES}?options=-csearch_path%3D{schema}"
            with sa.create_engine(POSTGRES).begin() as connection:
                connection.execute(sa.text(f"CREATE SCHEMA {schema}"))
        try:
            settings = Settings(_env_file=None, home=Path(home), database_url=url)  # type: ignore[call-arg]
            engine = create_db_engine(settings.resolved_database_url)
            migrate(engine)
            session_factory = create_session_factory(engine)
            run_id, token = fill(session_factory, args.frames)
            if args.reverse_indexes and args.database == "sqlite":
                reverse_indexes(engine)
            if args.database == "postgresql":  # the statistics autovacuum would have gathered
                with engine.begin() as connection:
                    connection.execute(sa.text("ANALYZE frames"))
                    connection.execute(sa.text("ANALYZE label_facets"))
            headers = {"Authorization": f"Bearer {token}"}
            app = create_app(settings)
            made = "indexes made in reverse order" if args.reverse_indexes else "indexes by name"
            print(f"{args.frames} frames in one run, {args.database} ({made}); page of {PAGE}\n")
            print("| list | page | API ms | server ms | SQL floor ms | server ÷ by id's, paired |")
            print("|---|---|---:|---:|---:|---:|")
            firsts: dict[str, float] = {}
            plain_pages: dict[str, Any] = {}
            with TestClient(app) as client, engine.connect() as connection:
                for order, status, name in LISTS:
                    where = [Frame.sequence_id == run_id, *held(name)]
                    if status == "unreviewed":
                        where.append(sa.text(f"frames.{UNREVIEWED_SQL}"))
                    total = connection.scalar(
                        sa.select(sa.func.count()).select_from(Frame).where(*where)
                    )
                    last = max(0, total - PAGE)
                    for which, offset, by_cursor in (
                        ("first", 0, False),
                        ("last", last, False),
                        ("last", last, True),
                    ):
                        if by_cursor and offset == 0:  # one page: no cursor to follow
                            continue
                        after = (
                            cursor_before(app, run_id, order, status, offset, name)
                            if by_cursor
                            else None
                        )
                        path = (
                            f"/api/v1/frames?sequence_id={run_id}&order={order}&status={status}"
                            + (f"&class={name}" if name else "")
                            + f"&limit={PAGE}&"
                            + (f"after={after}" if after else f"offset={offset}")
                        )
                        api = median_ms(lambda p=path: client.get(p, headers=headers), args.runs)
                        page = functools.partial(
                            page_json, app, run_id, order, status, offset, after, name
                        )
                        server = median_ms(page, args.runs)
                        kind = "cursor" if after else which
                        plain_pages.setdefault(kind, page)  # the plain list's (by id) first
                        ratio = paired_ratio(page, plain_pages[kind], args.runs)
                        ordered, _ = listing.list_query(
                            sequence_id=run_id,
                            status=None if status == "all" else "unreviewed",
                            order=order,
                            facets=held(name),
                        )  # the page's query (with the index it names), reading the ids alone
                        floor_query = ordered.with_only_columns(Frame.id)
                        if after:
                            key = listing.parse_cursor(after, order)
                            assert isinstance(key, list)
                            nulls_first = args.database == "sqlite"
                            floor_query = floor_query.where(
                                listing.after_condition(order, key, nulls_first, run_id)
                            ).limit(PAGE)
                        else:
                            floor_query = floor_query.limit(PAGE).offset(offset)
                        floor = median_ms(
                            lambda q=floor_query: connection.execute(q).all(), args.runs
                        )
                        how = "cursor" if after else f"offset {offset}"
                        label = f"{order} ({status})" + (f" class={name}" if name else "")
                        if which == "first":
                            firsts[label] = server
                        print(
                            f"| {label} | {which} ({how}) | {api:.1f} | "
                            f"{server:.1f} | {floor:.2f} | {ratio:.2f}× |",
                            flush=True,
                        )
            others = statistics.median(firsts[o] for o in ("id (all)", "frame_index (all)"))
            print(
                f"\nthe queue's first page (its diversity pick included) ÷ the other lists' first "
                f"pages, server time: {firsts['uncertainty (unreviewed)'] / others:.2f}×"
            )
            print(
                "a class filter's first page ÷ the plain list's (by id), server time: "
                f"wire {firsts['id (all) class=wire'] / firsts['id (all)']:.2f}×, "
                f"pool {firsts['id (all) class=pool'] / firsts['id (all)']:.2f}×"
            )
            print(f"RSS of this process: {rss_mb():.0f} MB")
            engine.dispose()
        finally:
            if args.database == "postgresql":
                with sa.create_engine(POSTGRES).begin() as connection:
                    connection.execute(sa.text(f"DROP SCHEMA {schema} CASCADE"))


if __name__ == "__main__":
    with recorded(__file__):
        main()
