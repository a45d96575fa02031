"""Settings come from the environment and a .env file, with the defaults of CONTRACT.md."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from app.core.config import Settings


def test_defaults_match_the_contract(monkeypatch: pytest.MonkeyPatch) -> None:
    for name in ("HOME", "DATABASE_URL", "QUEUE_URL", "DINO", "SAM2", "DEVICE", "RETRAIN_EVERY"):
        monkeypatch.delenv(f"WELDPOOL_{name}", raising=False)
    settings = Settings(_env_file=None)  # type: ignore[call-arg]
    assert settings.home == Path("./weldpool-data")
    assert settings.resolved_database_url.startswith("sqlite:///")
    assert settings.resolved_database_url.endswith("weldpool-data/weldpool.sqlite3")
    assert settings.queue_url is None
    assert settings.dino == "facebook/dino-vits8"
    assert settings.sam2 == "facebook/sam2.1-hiera-tiny"
    assert settings.device == "auto"
    assert settings.retrain_every == 20


def test_environment_overrides(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("WELDPOOL_HOME", str(tmp_path))
    monkeypatch.setenv("WELDPOOL_QUEUE_URL", "redis://127.0.0.1:6379/3")
    monkeypatch.setenv("WELDPOOL_RETRAIN_EVERY", "0")
    settings = Settings(_env_file=None)  # type: ignore[call-arg]
    assert settings.home == tmp_path
    assert settings.resolved_database_url == f"sqlite:///{tmp_path.resolve()}/weldpool.sqlite3"
    assert settings.queue_url == "redis://127.0.0.1:6379/3"
    assert settings.retrain_every == 0


def test_dotenv_file_is_honoured(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.delenv("WELDPOOL_DEVICE", raising=False)
    env_file = tmp_path / ".env"
    env_file.write_text("WELDPOOL_DEVICE=cpu\nWELDPOOL_DINO=/models/dino\n")
    settings = Settings(_env_file=env_file)  # type: ignore[call-arg]
    assert settings.device == "cpu"
    assert settings.dino == "/models/dino"


def test_bad_values_are_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("WELDPOOL_QUEUE_URL", "amqp://broker")
    with pytest.raises(ValidationError, match="redis://"):
        Settings(_env_file=None)  # type: ignore[call-arg]
    monkeypatch.delenv("WELDPOOL_QUEUE_URL")
    monkeypatch.setenv("WELDPOOL_RETRAIN_EVERY", "-1")
    with pytest.raises(ValidationError):
        Settings(_env_file=None)  # type: ignore[call-arg]
