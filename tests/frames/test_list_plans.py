"""On SQLite, the lists and the queue read the index named for them whatever the order their
indexes were made in: the planner has no statistics and would otherwise take the first of the
indexes it costs alike, which differed between homes."""

from __future__ import annotations

from typing import Any

import pytest
import sqlalchemy as sa

from app.core.db import create_db_engine, create_session_factory
from app.core.models import Frame, FrameStatus, Sequence
from app.core.schema import migrate
from app.frames.listing import list_query

# (order, status, run or all, the page's index or None where any index in order will do,
# the count's index or None where the planner's choice is free)
CASES = [
    ("uncertainty", "unreviewed", True, "ix_frames_queue_sequence", "ix_frames_queue_sequence"),
    ("uncertainty", "unreviewed", False, "ix_frames_queue", "ix_frames_queue"),
    ("uncertainty", None, True, "ix_frames_sequence_uncertainty", "ix_frames_sequence_id"),
    ("uncertainty", None, False, "ix_frames_uncertainty_order", None),
    ("id", "unreviewed", True, None, "ix_frames_queue_sequence"),
    ("id", None, True, None, "ix_frames_sequence_id"),
]


def _remake_indexes(connection: Any, reverse: bool) -> list[str]:
    """The frames table's indexes dropped and made again by name, or in the reverse order."""
    rows = connection.exec_driver_sql(
        "SELECT name, sql FROM sqlite_master WHERE type = 'index' AND tbl_name = 'frames' "
        "AND sql IS NOT NULL ORDER BY name"
    ).all()
    for name, _ in rows:
        connection.exec_driver_sql(f"DROP INDEX {name}")
    for _, sql in reversed(rows) if reverse else rows:
        connection.exec_driver_sql(sql)
    return [name for name, _ in rows]


def _plan(connection: Any, query: Any) -> str:
    sql = query.compile(connection, compile_kwargs={"literal_binds": True})
    rows = connection.exec_driver_sql(f"EXPLAIN QUERY PLAN {sql}").all()
    return "\n".join(row[-1] for row in rows)


@pytest.fixture
def sqlite_sessions(tmp_path: Any) -> Any:
    """Sessions on a new SQLite home (its schema made at once from the models)."""
    engine = create_db_engine(f"sqlite:///{tmp_path}/weldpool.sqlite3")
    migrate(engine)
    yield create_session_factory(engine)
    engine.dispose()


@pytest.mark.parametrize("reverse", [False, True], ids=["by name", "reversed"])
def test_list_and_queue_plans_do_not_depend_on_the_order_indexes_were_made_in(
    sqlite_sessions: Any, reverse: bool
) -> None:
    """Each page and count of a run's lists, the queue's above all, reads its own index in
    either order of creation: the queue's count reads the partial index alone (not every row
    of the run), the uncertainty order without a status reads an index in order (no sort)."""
    with sqlite_sessions() as session:
        run = Sequence(name="run")
        session.add(run)
        session.flush()
        rows = [
            {
                "sequence_id": run.id,
                "sha256": f"{i:064x}",
                "path": f"f/{i}.png",
                "media_type": "image/png",
                "size_bytes": 1,
                "width": 8,
                "height": 8,
                "status": FrameStatus.proposed if i % 3 else FrameStatus.accepted,
                "uncertainty": i / 100 if i % 4 else None,
            }
            for i in range(100)
        ]
        session.execute(sa.insert(Frame), rows)
        session.commit()
        connection = session.connection()
        names = _remake_indexes(connection, reverse)
        for order, status, one_run, page_index, count_index in CASES:
            ordered, count = list_query(
                sequence_id=run.id if one_run else None, status=status, order=order
            )
            case = (order, status, one_run)
            page = _plan(connection, ordered.limit(50).offset(40))
            assert "TEMP B-TREE" not in page, (case, page)
            if page_index:
                assert f"INDEX {page_index} " in page + " ", (case, page)
            counted = _plan(connection, count)
            if count_index:
                assert f"INDEX {count_index} " in counted + " ", (case, counted)
                others = [n for n in names if n != count_index and f"INDEX {n} " in counted + " "]
                assert not others, (case, counted)
            # the named index gives the list the planner's own choice would
            listed = session.scalars(ordered.limit(50).offset(40)).all()
            every = sorted(_all(session, run.id if one_run else None, status), key=_key(order))
            assert [f.id for f in listed] == [f.id for f in every][40:90]
            assert session.scalar(count) == len(every)


def _all(session: Any, run_id: int | None, status: str | None) -> list[Frame]:
    frames = list(session.scalars(sa.select(Frame)))
    return [
        f
        for f in frames
        if (run_id is None or f.sequence_id == run_id)
        and (status is None or f.status in (FrameStatus.new, FrameStatus.proposed))
    ]


def _key(order: str) -> Any:
    if order == "id":
        return lambda f: f.id
    return lambda f: (-(f.uncertainty if f.uncertainty is not None else -1.0), f.id)


def test_a_new_home_makes_each_tables_indexes_in_order_of_name(sqlite_sessions: Any) -> None:
    """A home made at once from the models gets its indexes in one order, by name."""
    with sqlite_sessions() as session:
        names = session.scalars(
            sa.text(
                "SELECT name FROM sqlite_master WHERE type = 'index' AND tbl_name = 'frames' "
                "AND sql IS NOT NULL"
            )
        ).all()
    assert names == sorted(names) and "ix_frames_queue_sequence" in names


def test_a_class_filter_reads_the_facets_index(sqlite_sessions: Any) -> None:
    """A list filtered by a class or tag looks its frames up in ``ix_label_facets_lookup``
    (never a scan of the facets), and its page still reads the frames in order (no sort)."""
    from app.core.models import LabelFacet
    from app.labelconfig.facets import filter_conditions
    from app.labelconfig.schemas import LabelConfigBody
    from app.labelconfig.service import Current

    config = LabelConfigBody.model_validate(
        {"classes": [{"name": "wire", "kind": "mask"}], "frame_tags": ["humping"]}
    ).model_dump(exclude_none=True)
    with sqlite_sessions() as session:
        rows = [
            {
                "sha256": f"{i:064x}",
                "path": f"f/{i}.png",
                "media_type": "image/png",
                "size_bytes": 1,
                "width": 8,
                "height": 8,
                "status": FrameStatus.corrected,
            }
            for i in range(200)
        ]
        session.execute(sa.insert(Frame), rows)
        ids = session.scalars(sa.select(Frame.id).order_by(Frame.id)).all()
        facets = [{"frame_id": i, "kind": "class", "key": "pool", "value": ""} for i in ids]
        facets += [{"frame_id": i, "kind": "class", "key": "wire", "value": ""} for i in ids[::7]]
        session.execute(sa.insert(LabelFacet), facets)
        session.commit()
        connection = session.connection()
        for given in ({"classes": ["wire"]}, {"tags": ["humping"]}):
            conditions = filter_conditions(Current(1, config), **given)  # type: ignore[arg-type]
            for order in ("id", "uncertainty"):
                ordered, count = list_query(order=order, facets=conditions)
                for plan in (_plan(connection, ordered.limit(50)), _plan(connection, count)):
                    assert "INDEX ix_label_facets_lookup" in plan, (given, order, plan)
                    assert "SCAN label_facets" not in plan, plan
        ordered, count = list_query(
            order="id", facets=filter_conditions(Current(1, config), ["wire"])
        )
        assert "TEMP B-TREE" not in _plan(connection, ordered.limit(50))
        assert [f.id for f in session.scalars(ordered.limit(50))] == list(ids[::7])
        assert session.scalar(count) == len(ids[::7])
