"""The job store: accepted optimization jobs in SQLite, durable before the 202 goes out.

One row per job. A job moves ``queued → running → succeeded | failed | cancelled``; a server
that dies leaves its jobs ``running``, and the next one to start puts them back in the queue
(:meth:`JobStore.recover`). Each run of a job has an ``attempt`` number, and a worker writes only
while its attempt is current, so a straggler from a dead server cannot overwrite a re-run.
Connections are opened per operation: the store is shared by request threads, the dispatcher
thread and worker processes.
"""

from __future__ import annotations

import json
import sqlite3
import time
import uuid
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

from .errors import StoreError

_SCHEMA = """
CREATE TABLE IF NOT EXISTS jobs (
    id               TEXT PRIMARY KEY,
    kind             TEXT NOT NULL,
    status           TEXT NOT NULL,
    request          TEXT NOT NULL,
    progress         TEXT,
    result           TEXT,
    error            TEXT,
    cancel_requested INTEGER NOT NULL DEFAULT 0,
    attempt          INTEGER NOT NULL DEFAULT 0,
    created_at       REAL NOT NULL,
    started_at       REAL,
    finished_at      REAL,
    updated_at       REAL NOT NULL
);
CREATE INDEX IF NOT EXISTS jobs_status ON jobs (status, created_at);
"""

FINAL = ("succeeded", "failed", "cancelled")


class JobStore:
    """Jobs in one SQLite file (WAL, fsync on commit)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        if self.path.is_dir():
            raise StoreError(f"job database {self.path}: is a directory (give a file path)")
        try:
            with self._db() as db:
                db.executescript(_SCHEMA)
                db.execute("SELECT id, kind, status, request, progress, result, error, "
                           "cancel_requested, attempt, created_at, started_at, finished_at, "
                           "updated_at FROM jobs LIMIT 1").fetchall()
        except sqlite3.DatabaseError as exc:  # not a database, or a database of something else
            raise StoreError(f"job database {self.path}: cannot be used ({exc}); move it away or "
                             "set EXCITE_DB_PATH to another file") from None

    @contextmanager
    def _db(self) -> Iterator[sqlite3.Connection]:
        db = sqlite3.connect(self.path, timeout=30, isolation_level=None)
        try:
            db.execute("PRAGMA journal_mode=WAL")
            db.execute("PRAGMA synchronous=FULL")
            db.row_factory = sqlite3.Row
            yield db
        finally:
            db.close()

    def ping(self) -> None:
        with self._db() as db:
            db.execute("SELECT count(*) FROM jobs").fetchone()

    # -- requests side --------------------------------------------------------------------

    def create(self, kind: str, request: dict[str, Any]) -> str:
        """Persist a queued job (committed and synced on return) and return its id."""
        job_id = uuid.uuid4().hex
        now = time.time()
        with self._db() as db:
            db.execute("INSERT INTO jobs (id, kind, status, request, created_at, updated_at) "
                       "VALUES (?, ?, 'queued', ?, ?, ?)",
                       (job_id, kind, json.dumps(request), now, now))
        return job_id

    def get(self, job_id: str) -> dict[str, Any] | None:
        with self._db() as db:
            row = db.execute("SELECT * FROM jobs WHERE id = ?", (job_id,)).fetchone()
        if row is None:
            return None
        out = dict(row)
        for key in ("request", "progress", "result", "error"):
            out[key] = None if out[key] is None else json.loads(out[key])
        return out

    def cancel(self, job_id: str) -> str | None:
        """Cancel a queued job at once, flag a running one; returns the status after, or None."""
        now = time.time()
        with self._db() as db:
            db.execute("BEGIN IMMEDIATE")
            row = db.execute("SELECT status FROM jobs WHERE id = ?", (job_id,)).fetchone()
            if row is None:
                db.execute("ROLLBACK")
                return None
            status = row["status"]
            if status == "queued":
                db.execute("UPDATE jobs SET status='cancelled', cancel_requested=1, finished_at=?, "
                           "updated_at=? WHERE id=?", (now, now, job_id))
                status = "cancelled"
            elif status == "running":
                db.execute("UPDATE jobs SET cancel_requested=1, updated_at=? WHERE id=?", (now, job_id))
            db.execute("COMMIT")
        return status

    def counts(self) -> dict[str, int]:
        with self._db() as db:
            rows = db.execute("SELECT status, count(*) AS n FROM jobs GROUP BY status").fetchall()
        return {r["status"]: r["n"] for r in rows}

    # -- dispatcher side ------------------------------------------------------------------

    def recover(self) -> list[str]:
        """Jobs a dead server left running go back to the queue (cancelled if asked); returns
        the ids of the re-queued ones."""
        now = time.time()
        with self._db() as db:
            db.execute("BEGIN IMMEDIATE")
            db.execute("UPDATE jobs SET status='cancelled', finished_at=?, updated_at=? "
                       "WHERE status='running' AND cancel_requested=1", (now, now))
            ids = [r[0] for r in db.execute("SELECT id FROM jobs WHERE status='running' "
                                            "ORDER BY created_at").fetchall()]
            db.execute("UPDATE jobs SET status='queued', updated_at=? WHERE status='running'", (now,))
            db.execute("COMMIT")
        return ids

    def claim(self) -> tuple[str, int] | None:
        """The oldest queued job, now running under a new attempt number."""
        now = time.time()
        with self._db() as db:
            db.execute("BEGIN IMMEDIATE")
            row = db.execute("SELECT id FROM jobs WHERE status='queued' ORDER BY created_at "
                             "LIMIT 1").fetchone()
            if row is None:
                db.execute("ROLLBACK")
                return None
            db.execute("UPDATE jobs SET status='running', attempt=attempt+1, started_at=?, "
                       "updated_at=? WHERE id=?", (now, now, row["id"]))
            attempt = db.execute("SELECT attempt FROM jobs WHERE id=?", (row["id"],)).fetchone()[0]
            db.execute("COMMIT")
        return row["id"], attempt

    def requeue(self, job_id: str, attempt: int) -> None:
        """A run stopped by a server shutdown: back to the queue for the next server."""
        with self._db() as db:
            db.execute("UPDATE jobs SET status='queued', updated_at=? WHERE id=? AND attempt=? "
                       "AND status='running'", (time.time(), job_id, attempt))

    # -- worker side (each write only for the current attempt of a running job) -------------

    def progress(self, job_id: str, attempt: int, progress: dict[str, Any]) -> None:
        with self._db() as db:
            db.execute("UPDATE jobs SET progress=?, updated_at=? WHERE id=? AND attempt=? AND "
                       "status='running'", (json.dumps(progress), time.time(), job_id, attempt))

    def should_stop(self, job_id: str, attempt: int) -> bool:
        """Whether the run must stop: cancelled, or no longer the current attempt."""
        with self._db() as db:
            row = db.execute("SELECT status, cancel_requested, attempt FROM jobs WHERE id=?",
                             (job_id,)).fetchone()
        return row is None or bool(row["cancel_requested"]) or row["attempt"] != attempt or \
            row["status"] != "running"

    def finish(self, job_id: str, attempt: int, status: str, result: dict[str, Any] | None = None,
               error: dict[str, Any] | None = None) -> bool:
        assert status in FINAL
        now = time.time()
        with self._db() as db:
            n = db.execute("UPDATE jobs SET status=?, result=?, error=?, finished_at=?, updated_at=? "
                           "WHERE id=? AND attempt=? AND status='running'",
                           (status, None if result is None else json.dumps(result),
                            None if error is None else json.dumps(error), now, now, job_id,
                            attempt)).rowcount
        return n == 1

    def cancel_requested_running(self) -> set[tuple[str, int]]:
        """(id, attempt) of running jobs asked to stop."""
        with self._db() as db:
            rows = db.execute("SELECT id, attempt FROM jobs WHERE status='running' AND "
                              "cancel_requested=1").fetchall()
        return {(r["id"], r["attempt"]) for r in rows}
