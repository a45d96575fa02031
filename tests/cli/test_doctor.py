"""`weldpool doctor`: the rows whose stored files are lost, each with what restores it."""

from __future__ import annotations

import sqlalchemy as sa

from app.core.config import Settings
from app.core.models import Frame, Label, Proposal
from app.demo import fill_demo
from tests.helpers import run_cli


def test_doctor_names_each_lost_file_its_row_and_what_restores_it(
    settings: Settings, session_factory
) -> None:
    with session_factory() as session:
        fill_demo(session, settings, frames=4, seed=3, progress=lambda _t: None)
        frame_id, image = session.execute(
            sa.select(Frame.id, Frame.path).order_by(Frame.id)
        ).first()
        labelled, mask = session.execute(
            sa.select(Label.frame_id, Label.mask_path)
            .where(Label.mask_path.is_not(None), Label.frame_id != frame_id)
            .order_by(Label.frame_id)
        ).first()
        shared = session.scalars(
            sa.select(Proposal.id).where(Proposal.mask_path == mask)
        ).all()  # a proposal accepted unchanged shares its mask file with the label
    env = {
        "WELDPOOL_HOME": str(settings.home),
        "WELDPOOL_DATABASE_URL": settings.resolved_database_url,
    }
    healthy = run_cli("doctor", env=env)
    assert healthy.returncode == 0, healthy.stderr
    assert healthy.stdout == "" and "every file the database names is in" in healthy.stderr

    (settings.home / image).unlink()
    (settings.home / mask).unlink()
    sick = run_cli("doctor", env=env)
    assert sick.returncode == 1, sick.stderr
    lines = sick.stdout.splitlines()
    assert f"frame {frame_id}: image {image} is missing; upload the same image again" in lines[0]
    assert lines[1] == (
        f"frame {labelled}: label mask {mask} is missing; draw and save the frame's label again "
        "to replace it"
    )
    assert len(lines) == 2 + len(shared)
    assert all("proposal mask" in line and mask in line for line in lines[2:])
    assert f"{len(lines)} files the database names are missing from {settings.home}" in sick.stderr
