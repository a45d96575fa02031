"""Settings: one object read from the environment (prefix ``WELDPOOL_``) and a ``.env`` file."""

from __future__ import annotations

import ipaddress
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Literal

from pydantic import Field, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from weldpool_core.defaults import DEFAULT_MAX_PIXELS, DEFAULT_WEIGHTS


@dataclass(frozen=True)
class StoreWaits:
    """How long one call to the object store may wait: to connect, for its answer (each
    attempt), and how many attempts."""

    connect_s: float
    read_s: float
    attempts: int

    @property
    def longest_s(self) -> float:
        """The longest one call waits on a store that never answers (backoff aside)."""
        return self.attempts * (self.connect_s + self.read_s)


class Settings(BaseSettings):
    """Everything the service can be configured with; each field's description is its row in the
    manual's settings reference (docs/reference/settings.md, generated from here)."""

    model_config = SettingsConfigDict(
        env_prefix="WELDPOOL_", env_file=".env", env_file_encoding="utf-8", extra="ignore"
    )

    home: Path = Field(
        default=Path("./weldpool-data"),
        description="Where the embedded default keeps its SQLite file, frames, models, caches.",
    )
    database_url: str | None = Field(
        default=None,
        description="SQLAlchemy URL, e.g. postgresql+psycopg://user:pw@host/db; default: the "
        "SQLite file weldpool.sqlite3 in home.",
    )
    queue_url: str | None = Field(
        default=None,
        description="redis://… for workers on other machines; default: SQLite queue file in home.",
    )
    storage_url: str | None = Field(
        default=None,
        description="s3://bucket/prefix to keep frames, masks, models and exports in an "
        "S3-compatible object store (home is then a bounded cache); default: the home folder.",
    )
    s3_endpoint_url: str | None = Field(
        default=None,
        description="The object store's endpoint for a store other than AWS S3 (MinIO, Ceph), "
        "e.g. http://minio:9000; credentials come from AWS_ACCESS_KEY_ID and friends.",
    )
    storage_connect_timeout_s: float = Field(
        default=3.0,
        gt=0,
        description="With an object store: how long a call waits to connect to it.",
    )
    storage_request_timeout_s: float = Field(
        default=10.0,
        gt=0,
        description="With an object store: how long a request's call (an upload, a read, "
        "/health, the check at start) waits for its answer, per attempt.",
    )
    storage_request_attempts: int = Field(
        default=2,
        ge=1,
        le=10,
        description="With an object store: how often a request's call is tried before the "
        "request answers 503.",
    )
    storage_job_timeout_s: float = Field(
        default=60.0,
        gt=0,
        description="With an object store: how long a job's call (and the command line's) waits "
        "for its answer, per attempt; workers may wait longer than a person.",
    )
    storage_job_attempts: int = Field(
        default=5,
        ge=1,
        le=20,
        description="With an object store: how often a job's call is tried before it fails.",
    )
    embedding_cache_mb: float = Field(
        default=20480.0,
        gt=0,
        description="SAM2 embeddings kept on disk under WELDPOOL_HOME/cache/embeddings (about "
        "4 MB a 1280×800 frame in fp16; least recently used out): the clicks' and propagation's "
        "cache; the Jobs page shows its size and (admins) clears it.",
    )
    storage_cache_mb: float = Field(
        default=10240.0,
        gt=0,
        description="With an object store: how much of it this machine keeps cached in home "
        "(least recently used files go first).",
    )
    shared_embeddings_days: float = Field(
        default=14.0,
        gt=0,
        description="With an object store: how long an embedding a machine computed stays "
        "shared in the store's embeddings/ for the others' first clicks (a cache, pruned by age "
        "after each teacher run).",
    )
    queue_name: str = Field(
        default="weldpool",
        description="Queue name; instances sharing one Redis need distinct names.",
    )
    dino: str = Field(default="facebook/dino-vits8", description="DINO hub id or local directory.")
    sam2: str = Field(
        default="facebook/sam2.1-hiera-tiny", description="SAM2 hub id or local directory."
    )
    dino_input_size: int = Field(
        default=480, ge=64, description="DINO sees frames resized to this square (multiple of 8)."
    )
    device: str = Field(default="auto", description="cpu, cuda, cuda:N, mps or auto.")
    teacher_batch: int = Field(
        default=0,
        ge=0,
        le=64,
        description="Frames a teacher run puts through DINO and SAM2's encoder at once: 0 "
        "batches each chunk's frames on a GPU and works one frame at a time on the CPU.",
    )
    review_stage: bool = Field(
        default=False,
        description="Labels annotators save await a reviewer's approval (or are sent back with "
        "a comment) and train only once approved; off: every saved label counts at once.",
    )
    student_class_min_labels: int = Field(
        default=10,
        ge=0,
        description="Reviewed labels a class other than the pool needs among a training's frames "
        "(those it trains on and those held out to measure it) before a student learns it as "
        "extra outputs; 0: the pool alone.",
    )
    retrain_every: int = Field(
        default=20,
        ge=0,
        description="New reviewed labels that start a training job; 0 turns it off.",
    )

    uncertainty_weights: dict[str, float] = Field(
        default_factory=lambda: dict(DEFAULT_WEIGHTS),
        description="Weights of the uncertainty components in the review queue's score, as JSON "
        "with the keys teacher_iou, instability, disagreement, student_uncertainty, "
        "propagation_doubt (each 1.0 by default).",
    )
    queue_diversity: float = Field(
        default=0.5,
        ge=0,
        le=1,
        description="0: the queue is the pure uncertainty ranking; up to 1: more diverse frames.",
    )
    queue_diversity_pool: int = Field(
        default=50,
        ge=1,
        le=2000,
        description="How many top-ranked frames the diversity pick reorders (it compares every "
        "pair of them: 2,000 is 32 MB a request).",
    )
    auto_promote: bool = Field(
        default=True, description="Promote a newly trained student when it beats the promoted one."
    )
    workers: int = Field(
        default=1, ge=1, description="Worker threads of one worker process's model lane."
    )
    quick_workers: int = Field(
        default=1,
        ge=1,
        description="Worker threads of one worker process's quick lane (exports, label "
        "imports, video extraction, int8), which never waits behind model work.",
    )
    interactive_threads: int | None = Field(
        default=None,
        ge=1,
        le=256,
        description="Threads of a click, a box or an embedding a reviewer waits for while a "
        "job runs on this machine (default: half the cores, at least 1: under contention a "
        "second thread buys a click nothing); with no job running a click uses every core.",
    )
    batch_threads: int | None = Field(
        default=None,
        ge=1,
        le=256,
        description="Threads of a worker's jobs (teacher runs, embeddings in bulk, training, "
        "propagation, export); default: every core.",
    )
    batch_nice: int = Field(
        default=10,
        ge=0,
        le=19,
        description="How much lower the worker's job threads run than the web process's "
        "(Linux nice), so a reviewer's click is never queued behind a job for the CPU; a fresh "
        "instance's admin hash at start runs as low, beside the imports.",
    )
    reviewer_active_s: float = Field(
        default=0.0,
        ge=0,
        description="If set, for this long after a reviewer's last click jobs on this machine "
        "also give up threads (batch threads minus interactive threads); 0 (default): jobs "
        "yield by priority alone, which measured as fast for clicks and costs training nothing "
        "(bench/interactive.py).",
    )
    job_heartbeat_s: float = Field(
        default=5.0, gt=0, description="How often a worker reports that it is alive."
    )
    job_stale_after_s: float = Field(
        default=60.0,
        gt=0,
        description="A running job whose worker is silent this long is failed or retried.",
    )
    file_grace_s: float = Field(
        default=900.0,
        ge=60,
        description="A stored file that no row names is removed once nobody has claimed it "
        "(written or reused it) for this long, in seconds (at least 60): far longer than any "
        "upload takes to commit.",
    )
    max_image_pixels: int = Field(
        default=DEFAULT_MAX_PIXELS,
        gt=0,
        description="Largest frame accepted, in pixels (a decompression-bomb guard; each frame "
        "in flight costs about 5 bytes per pixel while it is checked).",
    )
    max_request_mb: float = Field(
        default=2048.0, gt=0, description="Largest request body accepted, in MiB (413 above)."
    )
    max_files_per_request: int = Field(
        default=2000, ge=1, description="Most files one upload request may carry."
    )
    session_ttl_hours: float = Field(default=12.0, gt=0, description="Browser session lifetime.")
    login_max_failures: int = Field(
        default=5,
        ge=1,
        description="Wrong passwords for one user name (×4 for one client address) within "
        "login_lockout_minutes before further logins are refused with 429.",
    )
    login_lockout_minutes: float = Field(default=15.0, gt=0)
    cookie_secure: bool = Field(
        default=False, description="Send the session cookie over HTTPS only (set behind TLS)."
    )
    trusted_proxies: str = Field(
        default="",
        description="Reverse proxies (IP addresses or networks, comma-separated) whose "
        "X-Forwarded-For and X-Forwarded-Proto are believed; empty: none, so a client cannot "
        "choose the address the login lockout counts.",
    )
    live_bind_hosts: str = Field(
        default="127.0.0.1",
        description="Addresses the live view's ZeroMQ and OPC UA outputs may listen on "
        "(comma-separated; 0.0.0.0 serves the cell's network); empty: the live view opens none. "
        "Always on ports ≥ 1024, and for ZeroMQ only tcp://.",
    )
    live_mqtt_brokers: str = Field(
        default="127.0.0.1,localhost",
        description="Broker hosts the live view's MQTT output may publish to (comma-separated); "
        "empty: none.",
    )
    log_level: str = Field(
        default="INFO", description="DEBUG, INFO, WARNING or ERROR; logs go to stderr."
    )
    log_format: Literal["console", "json"] = Field(
        default="console", description="console for people, json for log collectors."
    )

    @field_validator("queue_url")
    @classmethod
    def _queue_scheme(cls, value: str | None) -> str | None:
        if value and not value.startswith(("redis://", "rediss://", "unix://")):
            raise ValueError("WELDPOOL_QUEUE_URL must be empty (embedded queue) or a redis://… URL")
        return value or None

    @field_validator("storage_url")
    @classmethod
    def _storage_scheme(cls, value: str | None) -> str | None:
        if value:
            from urllib.parse import urlparse

            parsed = urlparse(value)
            if parsed.scheme != "s3" or not parsed.netloc:
                raise ValueError(
                    "WELDPOOL_STORAGE_URL must be empty (the home folder) or s3://bucket/prefix"
                )
        return value or None

    @field_validator("trusted_proxies")
    @classmethod
    def _proxy_addresses(cls, value: str) -> str:
        proxies = []
        for proxy in (item.strip() for item in value.split(",") if item.strip()):
            try:  # 10.0.0.5/24 means its network: uvicorn reads networks strictly
                network = ipaddress.ip_network(proxy, strict=False)
            except ValueError:
                raise ValueError(
                    f"WELDPOOL_TRUSTED_PROXIES: {proxy!r} is not an IP address or network; give "
                    "addresses such as 10.0.0.5 or 10.0.0.0/24, separated by commas"
                ) from None
            proxies.append(proxy if "/" not in proxy else str(network))
        return ",".join(proxies)

    @property
    def trusted_proxy_list(self) -> list[str]:
        """The trusted proxies' addresses and networks (none by default)."""
        return self.trusted_proxies.split(",") if self.trusted_proxies else []

    def storage_waits(self, *, jobs: bool) -> StoreWaits:
        """How long a call to the object store waits: a job's (and the command line's), or a
        request's (the shorter bounds a person waits on)."""
        if jobs:
            return StoreWaits(
                self.storage_connect_timeout_s,
                self.storage_job_timeout_s,
                self.storage_job_attempts,
            )
        return StoreWaits(
            self.storage_connect_timeout_s,
            self.storage_request_timeout_s,
            self.storage_request_attempts,
        )

    @property
    def resolved_database_url(self) -> str:
        """The database URL, defaulting to a SQLite file in ``home``."""
        if self.database_url:
            return self.database_url
        return f"sqlite:///{(self.home / 'weldpool.sqlite3').resolve()}"

    @property
    def queue_file(self) -> Path:
        """The embedded queue's SQLite file (used when ``queue_url`` is not set)."""
        return self.home / "queue.sqlite3"

    def marker(self, name: str) -> Path:
        """A marker file this machine's processes share through the home (when a reviewer was
        last active, when a batch last ran): the service's own, never stored content."""
        return self.home / name

    def ensure_home(self) -> None:
        """Create the home directory and its standard subfolders."""
        for sub in ("", "frames", "artefacts", "models", "cache", "tmp"):
            (self.home / sub).mkdir(parents=True, exist_ok=True)


@lru_cache
def get_settings() -> Settings:
    """The process-wide settings, read once from the environment."""
    return Settings()
