"""Two imports of the same labels at once, and an import racing a reviewer: each frame ends with
one label and one frame row, nothing fails with a server error, on SQLite and PostgreSQL."""

from __future__ import annotations

import threading
from pathlib import Path

import sqlalchemy as sa

from app.core.models import Frame, Label, LabelRevision, Role, Sequence, User
from app.frames.sequences import create_sequence
from app.imports.schemas import ImportOptions
from app.imports.service import import_labels
from app.storage import open_storage
from tests.imports.common import masks_archive
from weldpool_core.annotations import open_source


def _archive(tmp_path: Path, count: int) -> Path:
    path = tmp_path / "labels.zip"
    path.write_bytes(masks_archive(count))
    return path


def test_two_imports_of_the_same_labels_at_once_write_each_frame_once(
    settings, session_factory, make_user, tmp_path: Path
) -> None:
    user, _ = make_user("twins", Role.annotator)
    archive = _archive(tmp_path, 70)  # two batches each
    with session_factory() as session:
        run_id = create_sequence(session, {"name": "one run"}, None).id
    reports, errors = [], []
    barrier = threading.Barrier(2)

    def run() -> None:
        try:
            with session_factory() as session:
                source = open_source(archive)
                barrier.wait()
                reports.append(
                    import_labels(
                        session,
                        open_storage(settings),
                        source,
                        ImportOptions("masks", sequence_id=run_id),
                        session.get_one(User, user.id),
                    )
                )
                source.close()
        except Exception as exc:
            errors.append(exc)

    threads = [threading.Thread(target=run) for _ in range(2)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(120)
    assert errors == []
    assert sum(r.labels for r in reports) == 70  # each frame labelled by one of them
    assert sum(len(r.skipped) for r in reports) == 70  # and skipped by the other
    with session_factory() as session:
        labels = session.scalar(sa.select(sa.func.count()).select_from(Label))
        revisions = session.scalar(sa.select(sa.func.count()).select_from(LabelRevision))
        names = session.scalars(sa.select(Frame.original_name)).all()
    assert labels == 70 and revisions == 70
    assert len(names) == len(set(names))  # no frame twice in its run


def test_two_imports_without_a_run_each_make_their_own(
    settings, session_factory, make_user, tmp_path: Path
) -> None:
    user, _ = make_user("pair", Role.annotator)
    archive = _archive(tmp_path, 3)
    barrier, errors = threading.Barrier(2), []

    def run(index: int) -> None:
        try:
            with session_factory() as session:
                source = open_source(archive, name="import-0.zip")
                barrier.wait()
                import_labels(
                    session,
                    open_storage(settings),
                    source,
                    ImportOptions("masks"),
                    session.get_one(User, user.id),
                )
                source.close()
        except Exception as exc:
            errors.append(exc)

    threads = [threading.Thread(target=run, args=(i,)) for i in range(2)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(60)
    assert errors == []
    with session_factory() as session:
        names = sorted(session.scalars(sa.select(Sequence.name)))
        labels = session.scalar(sa.select(sa.func.count()).select_from(Label))
        frames = session.scalar(sa.select(sa.func.count()).select_from(Frame))
    # The second finds those of the first's frames committed when it looked (by content) and
    # stores the others in a run of its own, never of the same name; every frame one label.
    assert names in (["import-0"], ["import-0", "import-0 (2)"])
    assert labels == frames and 3 <= frames <= 3 * len(names)


def test_an_import_others_keep_racing_stops_saying_what_it_wrote(
    settings, session_factory, make_user, tmp_path: Path, monkeypatch
) -> None:
    """A batch whose frames other writers keep changing is read and written again; when they
    never stop, the import stops with one sentence that says what it wrote and kept (it failed
    after committing the first batch's labels with no word of them)."""
    import app.imports.service as service
    from app.core.errors import ConflictError

    user, _ = make_user("racer", Role.annotator)
    archive = _archive(tmp_path, 70)  # a batch of 64, then 6
    written = service._Batch._write_labels
    tries: list[int] = []

    def raced(batch, targets) -> None:  # type: ignore[no-untyped-def]
        if len(targets) < 64:  # the second batch: others change its frames every time
            tries.append(len(targets))
            raise ConflictError("someone labelled it meanwhile")
        written(batch, targets)

    monkeypatch.setattr(service._Batch, "_write_labels", raced)
    with session_factory() as session:
        source = open_source(archive)
        try:
            import_labels(
                session,
                open_storage(settings),
                source,
                ImportOptions("masks"),
                session.get_one(User, user.id),
            )
        except ConflictError as exc:
            message = exc.message
        else:
            raise AssertionError("the import went on as if it had written every label")
        finally:
            source.close()
    assert tries == [6] * service.WRITE_ATTEMPTS
    assert message == (
        "Other writers kept labelling or deleting these frames while the import wrote them; it "
        "stopped after writing 64 labels and storing 70 new frames (those stay); import again "
        "to label the rest."
    )
    with session_factory() as session:
        assert session.scalar(sa.select(sa.func.count()).select_from(Label)) == 64
        assert session.scalar(sa.select(sa.func.count()).select_from(Frame)) == 70
