"""docker-compose.yml is valid Compose and starts what the Deploy page says (no Docker engine here).

The file is checked against the Compose specification (the compose-spec package, after YAML
anchors and merge keys are resolved as `docker compose` resolves them), and cross-checked with
this project: every command exists in the CLI and every WELDPOOL_ variable is a setting.
"""

from __future__ import annotations

import shlex

import yaml
from click.testing import CliRunner
from compose_spec import PyCompose

from app.cli import main
from app.core.config import Settings
from tests.helpers import REPO

COMPOSE = yaml.safe_load((REPO / "docker-compose.yml").read_text())
SERVICES = COMPOSE["services"]


def test_compose_file_follows_the_compose_specification() -> None:
    resolved = {k: v for k, v in COMPOSE.items() if not k.startswith("x-")}
    parsed = PyCompose.from_yaml(yaml.safe_dump(resolved))
    assert set(parsed.service_names()) == {
        *("postgres", "redis", "minio", "minio-bucket", "weights", "api", "worker", "worker-gpu")
    }


def test_services_depend_on_services_that_exist_and_become_healthy() -> None:
    for name, service in SERVICES.items():
        for dependency, condition in (service.get("depends_on") or {}).items():
            assert dependency in SERVICES, (name, dependency)
            if condition["condition"] == "service_healthy":
                assert "healthcheck" in SERVICES[dependency], dependency


def test_api_serves_without_worker_and_workers_scale() -> None:
    assert SERVICES["api"]["command"][:2] == ["weldpool", "serve"]
    assert "--no-worker" in SERVICES["api"]["command"]
    for name in ("worker", "worker-gpu"):
        worker = SERVICES[name]
        assert worker["command"][:2] == ["weldpool", "worker"]
        # --scale worker=N needs workers without fixed names or published ports.
        assert "container_name" not in worker and "ports" not in worker
    gpu = SERVICES["worker-gpu"]
    assert gpu["profiles"] == ["gpu"]  # optional: only with --profile gpu
    assert gpu["deploy"]["resources"]["reservations"]["devices"][0]["capabilities"] == ["gpu"]
    assert gpu["environment"]["WELDPOOL_DEVICE"] == "cuda"
    assert "cu" in gpu["build"]["args"]["TORCH_INDEX"].rsplit("/", 1)[-1]  # a CUDA build
    assert gpu["command"][2:] == ["--lanes", "model"]


def test_passwords_come_from_the_environment_and_weights_reach_every_worker() -> None:
    """No password is written in the file: the database's, Redis's and MinIO's come from .env
    (compose refuses to start without them); the weights volume is mounted read-only by the
    api and every worker, and written only by the one-shot weights service."""
    text = (REPO / "docker-compose.yml").read_text()
    for variable in ("WELDPOOL_DB_PASSWORD", "WELDPOOL_REDIS_PASSWORD", "WELDPOOL_S3_PASSWORD"):
        assert f"${{{variable}:?" in text
        assert f"{variable}=" in (REPO / ".env.example").read_text()
    assert "weldpool-secret" not in text and ":weldpool@" not in text
    assert "--requirepass" in SERVICES["redis"]["command"]
    for name in ("api", "worker", "worker-gpu"):
        assert "weldpool-weights:/weights:ro" in SERVICES[name]["volumes"], name
        assert SERVICES[name]["environment"]["HF_HUB_CACHE"] == "/weights"
    assert SERVICES["weights"]["volumes"] == ["weldpool-weights:/weights"]
    assert SERVICES["weights"]["command"] == ["weldpool", "weights", "fetch"]


def test_commands_and_variables_exist_in_this_project() -> None:
    fields = {f"WELDPOOL_{name.upper()}" for name in Settings.model_fields}
    runner = CliRunner()
    for name, service in SERVICES.items():
        env = service.get("environment") or {}
        unknown = {k for k in env if k.startswith("WELDPOOL_")} - fields
        assert not unknown, (name, unknown)
        command = service.get("command")
        if command and command[0] == "weldpool":
            args = command[1:] if isinstance(command, list) else shlex.split(command)[1:]
            result = runner.invoke(main, [*args, "--help"])
            assert result.exit_code == 0, (name, result.output)
    assert SERVICES["api"]["environment"]["WELDPOOL_DATABASE_URL"].startswith(
        "postgresql+psycopg://"
    )
    assert SERVICES["worker"]["environment"]["WELDPOOL_QUEUE_URL"].startswith("redis://")


def test_workers_share_no_volume_only_the_three_urls() -> None:
    """Files go through MinIO's bucket: no weldpool container mounts a volume another one does,
    and every one names the same database, queue and storage."""
    mounts: dict[str, str] = {}
    for name in ("api", "worker", "worker-gpu"):
        service = SERVICES[name]
        for volume in service.get("volumes") or []:
            if volume.endswith(":ro"):
                continue  # read-only: the weights every worker reads
            source = volume.split(":")[0]
            assert source not in mounts, (name, mounts[source])
            mounts[source] = name
        env = service["environment"]
        assert env["WELDPOOL_STORAGE_URL"] == "s3://weldpool/lab"
        assert env["WELDPOOL_S3_ENDPOINT_URL"] == "http://minio:9000"
        assert SERVICES[name]["depends_on"]["minio-bucket"]["condition"] == (
            "service_completed_successfully"
        )
    assert "healthcheck" in SERVICES["minio"]
