"""Service settings, read from the environment (``EXCITE_`` prefix) and validated at start-up.

Every bound a client can hit is here, so that a 413/422 can quote it.
"""

from __future__ import annotations

import os
from pathlib import Path

from typing import Literal

from pydantic import Field, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from excite.core import bounds

from .store import is_postgres_url


def default_db_path() -> Path:
    """``$XDG_DATA_HOME/excite/jobs.sqlite3`` (``~/.local/share/excite/jobs.sqlite3``): a user's
    data, never relative to the working directory."""
    base = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(base) / "excite" / "jobs.sqlite3"


class Settings(BaseSettings):
    """How the service runs and what it accepts. ``EXCITE_<NAME>`` sets each field."""

    model_config = SettingsConfigDict(env_prefix="EXCITE_", extra="ignore", frozen=True)

    db_path: Path = Field(default_factory=default_db_path, validate_default=True,
                          description="SQLite file holding accepted optimization jobs "
                                      "(default: $XDG_DATA_HOME/excite/jobs.sqlite3).")
    workers: int = Field(1, ge=0, le=64,
                         description="Optimization jobs run at once, each in its own process "
                                     "(0: accept and persist jobs but run none).")
    score_workers: int = Field(2, ge=1, le=64,
                               description="Processes that score routes for /v1/score and /v1/batch.")
    max_body_bytes: int = Field(16 * 1024 * 1024, ge=1024, le=1024**3,
                                description="Largest request body accepted [bytes].")
    max_route_duration_s: float = Field(3600.0, gt=0, le=bounds.MAX_DURATION_S, allow_inf_nan=False,
                                        description="Longest route scored or maneuver planned [s].")
    max_route_length_m: float = Field(100_000.0, gt=0, le=bounds.MAX_LENGTH_M, allow_inf_nan=False,
                                      description="Longest waypoint route (sum of chords) [m].")
    max_samples: int = Field(200_000, ge=10, le=bounds.MAX_SAMPLES,
                             description="Most poses, waypoints, knots or text lines in one route.")
    max_batch_routes: int = Field(64, ge=1, le=10_000, description="Most routes in one batch.")
    request_timeout_s: float = Field(60.0, gt=0, le=3600, allow_inf_nan=False,
                                     description="Time limit of one request [s].")
    max_job_time_budget_s: float = Field(900.0, gt=0, le=bounds.OPTIMIZE["time_budget_s"].hi,
                                         allow_inf_nan=False,
                                         description="Largest optimizer time budget a job may ask for [s].")
    cancel_grace_s: float = Field(15.0, gt=0, le=600, allow_inf_nan=False,
                                  description="A cancelled job that has not stopped by then is killed [s].")
    worker_memory_mb: int = Field(6144, ge=0, le=1_048_576,
                                  description="Address-space limit of each worker process [MiB] (0: none).")
    worker_recycle_mb: int = Field(512, ge=0, le=1_048_576,
                                   description="A scoring worker whose resident memory grew by more "
                                               "than this after a task is replaced [MiB] (0: never).")
    max_queued_tasks: int = Field(16, ge=0, le=10_000,
                                  description="Scoring tasks that may wait for a busy worker. A request "
                                              "that would queue past it, or whose wait would outlast "
                                              "its time limit, gets 429 with Retry-After at once.")
    header_timeout_s: float = Field(10.0, gt=0, le=3600, allow_inf_nan=False,
                                    description="Time limit to receive a request's headers [s] (a "
                                                "client that sends them slowly, or nothing, is "
                                                "answered 408 and disconnected).")
    body_timeout_s: float = Field(30.0, gt=0, le=3600, allow_inf_nan=False,
                                  description="Time limit to receive a request body [s] (slow "
                                              "clients get 408 and the connection is closed).")

    # -- who may do what (api.auth) ------------------------------------------------------------
    api_keys_file: Path | None = Field(
        None, description="YAML or JSON file of API keys (hashed, with scopes and owners; "
                          "`python -m api.keys new`). Unset: the server is open (everyone is admin).")
    open: bool = Field(False, description="Serve without API keys on a non-loopback address "
                                          "(refused at start-up otherwise).")
    docs: Literal["public", "authenticated", "off"] = Field(
        "authenticated", description="Who gets /docs and /openapi.json when keys are configured.")
    metrics: Literal["public", "admin", "off"] = Field(
        "admin", description="Who gets /metrics when keys are configured.")
    allowed_hosts: str = Field(
        "", max_length=10_000, description="Comma-separated host names the server answers to (the Host "
                                           "header; * for any). Default: the loopback names (localhost, "
                                           "127.0.0.1, ::1) for an open server, any for one with API keys.")
    allowed_origins: str = Field(
        "", max_length=10_000, description="Comma-separated origins (https://host:port) besides the "
                                           "server's own (scheme://host of a host named in "
                                           "EXCITE_ALLOWED_HOSTS) that may open /v1/live and post to it from a browser.")
    quota_jobs: int = Field(20, ge=0, le=100_000, description="Queued and running jobs per key.")
    quota_live_sessions: int = Field(4, ge=0, le=1000, description="/v1/live sessions per key at once.")
    quota_rate_per_s: float = Field(20.0, gt=0, le=100_000, allow_inf_nan=False,
                                    description="Requests per second per key, on average (per replica).")
    quota_burst: int = Field(40, ge=1, le=100_000, description="Requests per key at once above the rate.")
    quota_storage_mb: int = Field(256, ge=1, le=1_048_576,
                                  description="Stored jobs (requests and results) and scenes per key [MiB]: "
                                              "beyond it the key's own oldest finished jobs and least recently "
                                              "used scenes are deleted, and a new job or scene that its "
                                              "unfinished jobs leave no room for is refused (429).")
    score_share: float = Field(0.5, gt=0, le=1, allow_inf_nan=False,
                               description="Share of the scoring workers one key may hold at once while "
                                           "other keys wait (at least one worker).")

    # -- the job store (api.store) -------------------------------------------------------------
    database_url: str | None = Field(
        None, description="postgresql://user:password@host:port/db: jobs in PostgreSQL, shared by "
                          "several replicas (default: the SQLite file EXCITE_DB_PATH).")
    job_lease_s: float = Field(30.0, ge=1, le=3600, allow_inf_nan=False,
                               description="A running job's lease: renewed every third of it; a job "
                                           "whose replica stopped renewing is re-run after it [s].")
    job_time_reserve_s: float = Field(60.0, ge=0, le=3600, allow_inf_nan=False,
                                      description="A job is stopped (failed) at its time_budget_s plus "
                                                  "this, whatever it is doing [s].")
    retention_days: float = Field(7.0, gt=0, le=3650, allow_inf_nan=False,
                                  description="Finished jobs older than this are deleted [days].")
    min_free_mb: int = Field(64, ge=0, le=1_048_576,
                             description="Below this free space on the job database's or the temporary "
                                         "folder's disk, /readyz fails and bag uploads get 503 [MiB].")

    # -- bounds of the newer surfaces -----------------------------------------------------------
    max_lot_vertices: int = Field(1000, ge=4, le=100_000,
                                  description="Most vertices of a GeoJSON lot (outline, keep-out zones "
                                              "and terrain together).")
    max_live_pose_rate_hz: float = Field(400.0, gt=0, le=100_000, allow_inf_nan=False,
                                         description="Densest pose stream a /v1/live session may send, "
                                                     "over each message [Hz].")
    live_memory_mb: int = Field(3072, ge=0, le=1_048_576,
                                description="Address-space limit of each /v1/live session's process [MiB] (0: none).")
    max_live_sessions: int = Field(16, ge=0, le=64,
                                   description="/v1/live sessions streaming at once (each its own process).")
    max_scene_bytes: int = Field(16 * 1024 * 1024, ge=1024, le=1024**3,
                                 description="Largest scene file POST /v1/scenes keeps [bytes] (the body "
                                             "limit EXCITE_MAX_BODY_BYTES bounds the upload too).")

    dask_scheduler: str | None = Field(
        None, description="Dask scheduler (tcp://host:8786) that runs batch routes and optimization jobs "
                          "(default: none, local processes). Its workers need excite installed.")

    @field_validator("dask_scheduler")
    @classmethod
    def _scheduler(cls, v: str | None) -> str | None:
        from excite.errors import EngineError
        from excite.core.engine import scheduler_address

        if not v:
            return None
        try:
            return scheduler_address(v)
        except EngineError as exc:
            raise ValueError(str(exc).replace("--scheduler: ", "")) from None

    @field_validator("database_url")
    @classmethod
    def _database_url(cls, v: str | None) -> str | None:
        if not v:
            return None
        if not is_postgres_url(v):
            raise ValueError("must be a postgresql:// URL (SQLite: set EXCITE_DB_PATH instead)")
        return v

    @field_validator("api_keys_file", mode="before")  # before "" would be read as the path "."
    @classmethod
    def _keys_file(cls, v: str | Path | None) -> Path | None:
        if v is None or str(v) == "":
            return None
        v = Path(v).expanduser().resolve()
        if not v.is_file():
            raise ValueError(f"{v} is not a file")
        return v

    def hosts(self, open_server: bool) -> tuple[str, ...]:
        """The host names the server answers to (see ``allowed_hosts``)."""
        named = tuple(h.strip().lower().strip("[]") for h in self.allowed_hosts.split(",") if h.strip())
        return named or (("localhost", "127.0.0.1", "::1") if open_server else ("*",))

    @property
    def origins(self) -> tuple[str, ...]:
        return tuple(o.strip().rstrip("/").lower() for o in self.allowed_origins.split(",") if o.strip())

    @field_validator("db_path")
    @classmethod
    def _db_file(cls, v: Path) -> Path:
        v = v.expanduser().resolve()
        if v.is_dir():
            raise ValueError(f"{v} is a directory; give the path of a file")
        if v == default_db_path().expanduser().resolve():
            v.parent.mkdir(parents=True, exist_ok=True)
        elif not v.parent.is_dir():
            raise ValueError(f"directory {v.parent} does not exist")
        return v
