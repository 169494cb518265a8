"""Ids are never reused (issue 16, finding 12): a row deleted and a new one added get different ids, so the audit
trail and old job specs keep naming what they named; the migration that adds AUTOINCREMENT keeps every row."""

from __future__ import annotations

from sqlalchemy import delete, func, select

from fringelab.core.db import make_engine, make_sessionmaker, upgrade_database
from fringelab.core.models import AuditEvent, Camera, Experiment


def _add_experiment(sessions, name: str) -> tuple[int, int]:  # type: ignore[no-untyped-def]
    with sessions() as session:
        experiment = Experiment(name=name)
        camera = Camera(experiment=experiment, name="left", image_width_px=64, image_height_px=48, pixel_pitch_um=20)
        session.add_all([experiment, camera])
        session.commit()
        return experiment.id, camera.id


def test_the_id_of_a_deleted_row_is_not_given_again(tmp_path):
    url = f"sqlite:///{tmp_path / 'fringelab.db'}"
    upgrade_database(url)
    engine = make_engine(url)
    sessions = make_sessionmaker(engine)
    first, first_camera = _add_experiment(sessions, "first")
    with sessions() as session:
        session.delete(session.get(Experiment, first))  # the highest id: plain SQLite would hand it out again
        session.add(AuditEvent(username="ada", action="delete", object_type="experiment", object_id=str(first),
                               detail={}))  # fmt: skip
        session.commit()
    second, second_camera = _add_experiment(sessions, "second")
    engine.dispose()
    assert second > first and second_camera > first_camera


def test_the_migration_keeps_rows_and_their_children(tmp_path):
    url = f"sqlite:///{tmp_path / 'fringelab.db'}"
    upgrade_database(url, "0005")
    engine = make_engine(url)
    sessions = make_sessionmaker(engine)
    kept, kept_camera = _add_experiment(sessions, "kept")
    dropped, _ = _add_experiment(sessions, "dropped")
    with sessions() as session:  # SQL, not the ORM: today's models know tables this revision does not have yet
        session.execute(delete(Experiment).where(Experiment.id == dropped))
        session.commit()
    engine.dispose()
    upgrade_database(url)  # rebuilds the tables: dropping the old ones must cascade nowhere
    engine = make_engine(url)
    sessions = make_sessionmaker(engine)
    with sessions() as session:
        assert session.get(Camera, kept_camera).experiment_id == kept  # type: ignore[union-attr]
        assert session.scalar(select(func.count()).select_from(Camera)) == 1
    after, _ = _add_experiment(sessions, "after")
    engine.dispose()
    assert after > kept
