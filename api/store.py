"""The job store: accepted optimization jobs, durable before the 202 goes out, shared by every
replica of the service.

Two back ends with one behaviour: SQLite (a file; the embedded default, one host, WAL, fsync on
commit) and PostgreSQL (``EXCITE_DATABASE_URL=postgresql://…``: several replicas on one
database, :mod:`psycopg` 3). :func:`open_store` picks one from a URL or a path.

A job moves ``queued → running → succeeded | failed | cancelled``. Each run of a job has an
``attempt`` number, and a worker writes only while its attempt is current, so a straggler can
never overwrite a re-run.

**Leases.** A replica claims a job with a lease (``lease_owner``, ``lease_expires``) and renews
the leases of all its running jobs with a heartbeat every third of the lease. A job whose lease
has expired (its replica died, or lost the database for longer than the lease) goes back to the
queue, by whichever replica sees it first (:meth:`JobStore.reclaim`); a job with a live lease is
never touched by another replica, however late that one starts. A lease held by a dead process
on this very host (same boot) is reclaimed at once, so a server restarted after ``kill -9``
re-runs its jobs without waiting for the lease to run out.

**Fairness.** :meth:`JobStore.claim` serves the key with the fewest running jobs first, then the
one served longest ago, then the oldest job: one key's hundreds of queued jobs delay another
key's job by at most one job slot.

**Retention.** :meth:`JobStore.purge` deletes finished jobs older than an age and, beyond a
total size, the oldest finished ones; :meth:`JobStore.finish` keeps of the request only what
the result's downloads need (:data:`KEPT_REQUEST_KEYS`).

**Migrations.** The schema carries a version (table ``excite_schema``); opening a store applies
the missing steps of :data:`MIGRATIONS` in one transaction (under an advisory lock on
PostgreSQL, so replicas that start together migrate once). Databases of servers before
versioning are version 1.

Every failure of the database is a :class:`~api.errors.StoreError` naming the store and what is
wrong (full, read-only, corrupt, unreachable), never a bare driver exception.
"""

from __future__ import annotations

import json
import os
import socket
import sqlite3
import threading
import time
import uuid
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

from .errors import StoreError

FINAL = ("succeeded", "failed", "cancelled")
# what a finished job's downloads need of its request (GET …/maneuver): the rest is dropped
KEPT_REQUEST_KEYS = ("rig", "name", "origin")
OPEN_KEY = ""  # the key id of jobs made without authentication (an open server)

_SQLITE_V1 = """
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
_PG_V1 = """
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
    created_at       DOUBLE PRECISION NOT NULL,
    started_at       DOUBLE PRECISION,
    finished_at      DOUBLE PRECISION,
    updated_at       DOUBLE PRECISION NOT NULL
);
CREATE INDEX IF NOT EXISTS jobs_status ON jobs (status, created_at);
"""


def _v2(real: str) -> str:
    return f"""
ALTER TABLE jobs ADD COLUMN key_id TEXT NOT NULL DEFAULT '';
ALTER TABLE jobs ADD COLUMN owner TEXT NOT NULL DEFAULT '';
ALTER TABLE jobs ADD COLUMN lease_owner TEXT;
ALTER TABLE jobs ADD COLUMN lease_expires {real};
ALTER TABLE jobs ADD COLUMN size_bytes INTEGER NOT NULL DEFAULT 0;
CREATE INDEX IF NOT EXISTS jobs_key_status ON jobs (key_id, status);
CREATE INDEX IF NOT EXISTS jobs_key_started ON jobs (key_id, started_at);
CREATE INDEX IF NOT EXISTS jobs_finished ON jobs (status, finished_at);
CREATE TABLE IF NOT EXISTS job_runs (
    job_id      TEXT NOT NULL,
    attempt     INTEGER NOT NULL,
    replica     TEXT NOT NULL,
    started_at  {real} NOT NULL,
    finished_at {real},
    outcome     TEXT,
    PRIMARY KEY (job_id, attempt)
);
UPDATE jobs SET size_bytes = length(request) + coalesce(length(result), 0)
    + coalesce(length(error), 0) + coalesce(length(progress), 0);
"""


# (version, SQLite script, PostgreSQL script): append, never edit a released step
MIGRATIONS: list[tuple[int, str, str]] = [
    (1, _SQLITE_V1, _PG_V1),
    (2, _v2("REAL"), _v2("DOUBLE PRECISION")),
]
SCHEMA_VERSION = MIGRATIONS[-1][0]

_JOB_COLUMNS = ("id, kind, status, progress, result, error, cancel_requested, attempt, created_at, "
                "started_at, finished_at, updated_at, key_id, owner, lease_owner, lease_expires")


def boot_id() -> str:
    try:
        return Path("/proc/sys/kernel/random/boot_id").read_text().strip()
    except OSError:
        return ""


def replica_id() -> str:
    """``host/boot/pid/random``: unique per server process, and enough to tell whether the
    process that holds a lease on this host is still alive."""
    return f"{socket.gethostname()}/{boot_id()[:8]}/{os.getpid()}/{uuid.uuid4().hex[:8]}"


def local_holder_dead(holder: str) -> bool:
    """Whether ``holder`` (a :func:`replica_id`) is a process of this host and boot that is gone."""
    try:
        host, boot, pid, _ = holder.split("/")
    except ValueError:
        return False
    if host != socket.gethostname() or boot != boot_id()[:8]:
        return False
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return True
    except (PermissionError, ValueError):
        return False
    return False


def _size(*texts: str | None) -> int:
    return sum(len(t) for t in texts if t)


def kept_request(request: dict[str, Any]) -> dict[str, Any]:
    return {k: request[k] for k in KEPT_REQUEST_KEYS if k in request}


class JobStore:
    """The store's operations, written once over a dialect (:class:`SqliteStore`,
    :class:`PostgresStore`). SQL is written with ``?`` placeholders."""

    url: str

    # -- dialect ----------------------------------------------------------------------------

    @contextmanager
    def _db(self) -> Iterator[Any]:
        raise NotImplementedError

    @contextmanager
    def _tx(self, db: Any, exclusive: bool = False) -> Iterator[None]:
        raise NotImplementedError

    def _x(self, db: Any, sql: str, params: tuple = ()) -> Any:
        return db.execute(sql, params)

    def _fault(self, exc: Exception) -> StoreError:
        raise NotImplementedError

    def describe(self) -> str:
        raise NotImplementedError

    @contextmanager
    def _session(self, exclusive: bool = False, tx: bool = False) -> Iterator[Any]:
        try:
            with self._db() as db:
                if tx:
                    with self._tx(db, exclusive):
                        yield db
                else:
                    yield db
        except StoreError:
            raise
        except Exception as exc:
            if _is_db_error(exc):
                raise self._fault(exc) from None
            raise

    def _migrate(self) -> None:
        with self._session(tx=True, exclusive=True) as db:
            self._x(db, "CREATE TABLE IF NOT EXISTS excite_schema (version INTEGER NOT NULL)")
            row = self._x(db, "SELECT max(version) AS v FROM excite_schema").fetchone()
            current = row["v"] or 0
            if current > SCHEMA_VERSION:
                raise StoreError(f"job database {self.describe()}: schema version {current} is newer "
                                 f"than this server's ({SCHEMA_VERSION}); upgrade the server")
            for version, lite, pg in MIGRATIONS:
                if version <= current:
                    continue
                for stmt in (lite if isinstance(self, SqliteStore) else pg).split(";"):
                    if stmt.strip():
                        self._x(db, stmt)
                self._x(db, "INSERT INTO excite_schema (version) VALUES (?)", (version,))
            # a database of something else that happens to have a jobs table
            self._x(db, f"SELECT {_JOB_COLUMNS}, request, size_bytes FROM jobs LIMIT 1").fetchall()

    def schema_version(self) -> int:
        with self._session() as db:
            return self._x(db, "SELECT max(version) AS v FROM excite_schema").fetchone()["v"]

    def ping(self) -> None:
        """Raises :class:`StoreError` when the database does not answer a read."""
        with self._session() as db:
            self._x(db, "SELECT count(*) AS n FROM excite_schema").fetchone()

    # -- requests side ----------------------------------------------------------------------

    def create(self, kind: str, request: dict[str, Any], key_id: str = OPEN_KEY, owner: str = "") -> str:
        """Persist a queued job (committed and synced on return) and return its id."""
        job_id = uuid.uuid4().hex
        now = time.time()
        text = json.dumps(request)
        with self._session() as db:
            self._x(db, "INSERT INTO jobs (id, kind, status, request, created_at, updated_at, key_id, "
                        "owner, size_bytes) VALUES (?, ?, 'queued', ?, ?, ?, ?, ?, ?)",
                    (job_id, kind, text, now, now, key_id, owner, len(text)))
        return job_id

    def get(self, job_id: str, key_id: str | None = None) -> dict[str, Any] | None:
        """The job (without its request), or None; with ``key_id``, only a job of that key."""
        sql = f"SELECT {_JOB_COLUMNS} FROM jobs WHERE id = ?"
        params: tuple = (job_id,)
        if key_id is not None:
            sql += " AND key_id = ?"
            params += (key_id,)
        with self._session() as db:
            row = self._x(db, sql, params).fetchone()
        if row is None:
            return None
        out = dict(row)
        for key in ("progress", "result", "error"):
            out[key] = None if out[key] is None else json.loads(out[key])
        return out

    def request_of(self, job_id: str) -> dict[str, Any] | None:
        with self._session() as db:
            row = self._x(db, "SELECT request FROM jobs WHERE id = ?", (job_id,)).fetchone()
        return None if row is None else json.loads(row["request"])

    def cancel(self, job_id: str, key_id: str | None = None) -> str | None:
        """Cancel a queued job at once, flag a running one; returns the status after, or None
        (no such job, or none of ``key_id``'s)."""
        now = time.time()
        with self._session(tx=True) as db:
            sql, params = "SELECT status FROM jobs WHERE id = ?", (job_id,)
            if key_id is not None:
                sql, params = sql + " AND key_id = ?", params + (key_id,)
            row = self._x(db, sql + self._for_update(), params).fetchone()
            if row is None:
                return None
            status = row["status"]
            if status == "queued":
                self._x(db, "UPDATE jobs SET status='cancelled', cancel_requested=1, finished_at=?, "
                            "updated_at=? WHERE id=?", (now, now, job_id))
                status = "cancelled"
            elif status == "running":
                self._x(db, "UPDATE jobs SET cancel_requested=1, updated_at=? WHERE id=?", (now, job_id))
        return status

    def counts(self) -> dict[str, int]:
        with self._session() as db:
            rows = self._x(db, "SELECT status, count(*) AS n FROM jobs GROUP BY status").fetchall()
        return {r["status"]: r["n"] for r in rows}

    def active(self, key_id: str) -> int:
        """Queued and running jobs of ``key_id`` (its quota counts these)."""
        with self._session() as db:
            row = self._x(db, "SELECT count(*) AS n FROM jobs WHERE key_id = ? AND status IN "
                              "('queued', 'running')", (key_id,)).fetchone()
        return row["n"]

    def runs(self, job_id: str) -> list[dict[str, Any]]:
        """Every run of a job: attempt, replica, start, end and outcome."""
        with self._session() as db:
            rows = self._x(db, "SELECT * FROM job_runs WHERE job_id = ? ORDER BY attempt",
                           (job_id,)).fetchall()
        return [dict(r) for r in rows]

    def _for_update(self) -> str:
        return ""

    # -- dispatcher side --------------------------------------------------------------------

    def claim(self, replica: str, lease_s: float) -> tuple[str, int] | None:
        """The next queued job by fairness (see the module docstring), now running under a new
        attempt and a lease of ``lease_s`` held by ``replica``."""
        now = time.time()
        with self._session(tx=True, exclusive=True) as db:
            keys = self._x(db, "SELECT key_id, min(created_at) AS first FROM jobs WHERE status='queued' "
                               "GROUP BY key_id").fetchall()
            if not keys:
                return None
            order = []
            for k in keys:
                running = self._x(db, "SELECT count(*) AS n FROM jobs WHERE key_id=? AND status='running'",
                                  (k["key_id"],)).fetchone()["n"]
                last = self._x(db, "SELECT max(started_at) AS t FROM jobs WHERE key_id=?",
                               (k["key_id"],)).fetchone()["t"]
                order.append((running, last or 0.0, k["first"], k["key_id"]))
            key_id = min(order)[3]
            row = self._x(db, "SELECT id FROM jobs WHERE key_id=? AND status='queued' ORDER BY created_at "
                              "LIMIT 1", (key_id,)).fetchone()
            self._x(db, "UPDATE jobs SET status='running', attempt=attempt+1, started_at=?, updated_at=?, "
                        "lease_owner=?, lease_expires=? WHERE id=?",
                    (now, now, replica, now + lease_s, row["id"]))
            attempt = self._x(db, "SELECT attempt FROM jobs WHERE id=?", (row["id"],)).fetchone()["attempt"]
            self._x(db, "INSERT INTO job_runs (job_id, attempt, replica, started_at) VALUES (?, ?, ?, ?)",
                    (row["id"], attempt, replica, now))
        return row["id"], attempt

    def heartbeat(self, replica: str, lease_s: float) -> set[tuple[str, int]]:
        """Renew the leases ``replica`` holds; returns the (id, attempt) it still holds."""
        now = time.time()
        with self._session(tx=True) as db:
            self._x(db, "UPDATE jobs SET lease_expires=? WHERE lease_owner=? AND status='running'",
                    (now + lease_s, replica))
            rows = self._x(db, "SELECT id, attempt FROM jobs WHERE lease_owner=? AND status='running'",
                           (replica,)).fetchall()
        return {(r["id"], r["attempt"]) for r in rows}

    def reclaim(self, replica: str) -> list[str]:
        """Running jobs whose lease expired, or whose holder is a dead process of this host, go
        back to the queue (cancelled if asked); returns the ids re-queued. A live lease of
        another replica is never touched."""
        now = time.time()
        with self._session(tx=True, exclusive=True) as db:
            rows = self._x(db, "SELECT id, attempt, lease_owner, lease_expires, cancel_requested FROM jobs "
                               "WHERE status='running' AND (lease_owner IS NULL OR lease_owner <> ?)",
                           (replica,)).fetchall()
            gone = [r for r in rows if r["lease_owner"] is None or (r["lease_expires"] or 0) < now
                    or local_holder_dead(r["lease_owner"])]
            out = []
            for r in gone:
                self._x(db, "UPDATE job_runs SET finished_at=?, outcome='lost' WHERE job_id=? AND attempt=? "
                            "AND finished_at IS NULL", (now, r["id"], r["attempt"]))
                if r["cancel_requested"]:
                    self._x(db, "UPDATE jobs SET status='cancelled', finished_at=?, updated_at=?, lease_owner=NULL "
                                "WHERE id=? AND attempt=?", (now, now, r["id"], r["attempt"]))
                else:
                    self._x(db, "UPDATE jobs SET status='queued', updated_at=?, lease_owner=NULL, "
                                "lease_expires=NULL WHERE id=? AND attempt=?", (now, r["id"], r["attempt"]))
                    out.append(r["id"])
        return out

    def release(self, job_id: str, attempt: int) -> None:
        """A run stopped by this server's shutdown: back to the queue for the next server."""
        now = time.time()
        with self._session(tx=True) as db:
            n = self._x(db, "UPDATE jobs SET status='queued', updated_at=?, lease_owner=NULL, lease_expires=NULL "
                            "WHERE id=? AND attempt=? AND status='running'", (now, job_id, attempt)).rowcount
            if n:
                self._x(db, "UPDATE job_runs SET finished_at=?, outcome='released' WHERE job_id=? AND attempt=?",
                        (now, job_id, attempt))

    def cancel_requested_running(self, replica: str | None = None) -> set[tuple[str, int]]:
        """(id, attempt) of running jobs asked to stop (of ``replica``'s when given)."""
        sql, params = "SELECT id, attempt FROM jobs WHERE status='running' AND cancel_requested=1", ()
        if replica is not None:
            sql, params = sql + " AND lease_owner=?", (replica,)
        with self._session() as db:
            rows = self._x(db, sql, params).fetchall()
        return {(r["id"], r["attempt"]) for r in rows}

    def purge(self, max_age_s: float, max_bytes: int) -> int:
        """Delete finished jobs older than ``max_age_s`` and, while the stored jobs hold more
        than ``max_bytes``, the oldest finished ones; returns how many were deleted."""
        now = time.time()
        deleted = 0
        with self._session(tx=True, exclusive=True) as db:
            old = [r["id"] for r in self._x(
                db, "SELECT id FROM jobs WHERE status IN ('succeeded', 'failed', 'cancelled') AND "
                    "finished_at < ?", (now - max_age_s,)).fetchall()]
            total = self._x(db, "SELECT coalesce(sum(size_bytes), 0) AS b FROM jobs").fetchone()["b"]
            if total > max_bytes:
                for r in self._x(db, "SELECT id, size_bytes FROM jobs WHERE status IN ('succeeded', 'failed', "
                                     "'cancelled') ORDER BY finished_at").fetchall():
                    if total <= max_bytes:
                        break
                    if r["id"] not in old:
                        old.append(r["id"])
                    total -= r["size_bytes"]
            for job_id in old:
                deleted += self._x(db, "DELETE FROM jobs WHERE id=?", (job_id,)).rowcount
                self._x(db, "DELETE FROM job_runs WHERE job_id=?", (job_id,))
        return deleted

    def total_bytes(self) -> int:
        with self._session() as db:
            return self._x(db, "SELECT coalesce(sum(size_bytes), 0) AS b FROM jobs").fetchone()["b"]

    # -- worker side (each write only for the current attempt of a running job) -------------

    def running_request(self, job_id: str, attempt: int) -> dict[str, Any] | None:
        """The request of the job's current run, or None when that run is no longer current."""
        with self._session() as db:
            row = self._x(db, "SELECT request FROM jobs WHERE id=? AND attempt=? AND status='running'",
                          (job_id, attempt)).fetchone()
        return None if row is None else json.loads(row["request"])

    def progress(self, job_id: str, attempt: int, progress: dict[str, Any]) -> None:
        with self._session() as db:
            self._x(db, "UPDATE jobs SET progress=?, updated_at=? WHERE id=? AND attempt=? AND "
                        "status='running'", (json.dumps(progress), time.time(), job_id, attempt))

    def should_stop(self, job_id: str, attempt: int) -> bool:
        """Whether the run must stop: cancelled, or no longer the current attempt."""
        with self._session() as db:
            row = self._x(db, "SELECT status, cancel_requested, attempt FROM jobs WHERE id=?",
                          (job_id,)).fetchone()
        return row is None or bool(row["cancel_requested"]) or row["attempt"] != attempt or \
            row["status"] != "running"

    def finish(self, job_id: str, attempt: int, status: str, result: dict[str, Any] | None = None,
               error: dict[str, Any] | None = None) -> bool:
        """The run's outcome, written once (only by the current attempt of a running job). The
        stored request shrinks to what the downloads need."""
        if status not in FINAL:
            raise ValueError(f"not a final status: {status!r}")
        now = time.time()
        res = None if result is None else json.dumps(result)
        err = None if error is None else json.dumps(error)
        with self._session(tx=True) as db:
            row = self._x(db, "SELECT request, progress FROM jobs WHERE id=? AND attempt=? AND status='running'"
                          + self._for_update(), (job_id, attempt)).fetchone()
            if row is None:
                return False
            req = json.dumps(kept_request(json.loads(row["request"])))
            self._x(db, "UPDATE jobs SET status=?, result=?, error=?, request=?, finished_at=?, updated_at=?, "
                        "lease_owner=NULL, size_bytes=? WHERE id=? AND attempt=?",
                    (status, res, err, req, now, now, _size(req, res, err, row["progress"]), job_id, attempt))
            self._x(db, "UPDATE job_runs SET finished_at=?, outcome=? WHERE job_id=? AND attempt=?",
                    (now, status, job_id, attempt))
        return True


def _is_db_error(exc: Exception) -> bool:
    if isinstance(exc, sqlite3.Error):
        return True
    try:
        import psycopg
    except ImportError:
        return False
    return isinstance(exc, psycopg.Error)


class SqliteStore(JobStore):
    """Jobs in one SQLite file (WAL, fsync on commit). Connections are opened per operation:
    the store is shared by request threads, the dispatcher thread and worker processes."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.url = str(self.path)
        if self.path.is_dir():
            raise StoreError(f"job database {self.path}: is a directory (give a file path)")
        self._migrate()

    def describe(self) -> str:
        return str(self.path)

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

    @contextmanager
    def _tx(self, db: sqlite3.Connection, exclusive: bool = False) -> Iterator[None]:
        db.execute("BEGIN IMMEDIATE")
        try:
            yield
        except BaseException:
            db.execute("ROLLBACK")
            raise
        db.execute("COMMIT")

    def _fault(self, exc: Exception) -> StoreError:
        text = str(exc)
        low = text.lower()
        folder = self.path.parent
        if "disk is full" in low or "disk i/o" in low:
            why = f"the disk is full or failing ({text}); free space on {folder}"
        elif "readonly" in low or "read-only" in low or (
                "unable to open" in low and not os.access(folder, os.W_OK)):
            why = (f"cannot write ({text}): the folder {folder} or the file is read-only; the server "
                   "needs write access to both (SQLite writes its journal beside the file)")
        elif "not a database" in low or "malformed" in low or "no such table" in low or "no such column" in low:
            why = f"cannot be used ({text}); move it away or set EXCITE_DB_PATH to another file"
        elif "locked" in low or "busy" in low:
            why = f"is busy ({text}); another process holds it"
        else:
            why = f"failed ({text})"
        return StoreError(f"job database {self.path}: {why}")


class PostgresStore(JobStore):
    """Jobs in a PostgreSQL database (several replicas share it). A few connections are kept
    per process and checked before use; claims and reclaims are serialised by an advisory
    lock."""

    LOCK = 0x657863697465  # 'excite'

    def __init__(self, url: str, max_idle: int = 4, connect_timeout_s: float = 10.0):
        import importlib.util

        if importlib.util.find_spec("psycopg") is None:
            raise StoreError("a PostgreSQL job store needs psycopg: pip install 'psycopg[binary]'")
        self.url = url
        self.max_idle, self.connect_timeout_s = max_idle, connect_timeout_s
        self._idle: list[Any] = []
        self._lock = threading.Lock()
        self._pid = os.getpid()
        self._migrate()

    def describe(self) -> str:
        from psycopg.conninfo import conninfo_to_dict

        try:
            info = conninfo_to_dict(self.url)
        except Exception:
            return "postgresql (unparsable URL)"
        return f"postgresql {info.get('host', 'localhost')}:{info.get('port', 5432)}/{info.get('dbname', '')}"

    def _connect(self) -> Any:
        import psycopg
        from psycopg.rows import dict_row

        return psycopg.connect(self.url, autocommit=True, row_factory=dict_row,
                               connect_timeout=int(self.connect_timeout_s))

    @contextmanager
    def _db(self) -> Iterator[Any]:
        if os.getpid() != self._pid:  # a forked child must not share its parent's sockets
            self._idle, self._pid = [], os.getpid()
        with self._lock:
            db = self._idle.pop() if self._idle else None
        if db is None or db.closed or db.broken:
            db = self._connect()
        ok = False
        try:
            yield db
            ok = True
        finally:
            if ok and not db.closed and not db.broken:
                with self._lock:
                    if len(self._idle) < self.max_idle:
                        self._idle.append(db)
                        db = None
            if db is not None:
                db.close()

    @contextmanager
    def _tx(self, db: Any, exclusive: bool = False) -> Iterator[None]:
        with db.transaction():
            if exclusive:
                db.execute("SELECT pg_advisory_xact_lock(%s)", (self.LOCK,))
            yield

    def _x(self, db: Any, sql: str, params: tuple = ()) -> Any:
        return db.execute(sql.replace("?", "%s"), params)

    def _for_update(self) -> str:
        return " FOR UPDATE"

    def _fault(self, exc: Exception) -> StoreError:
        text = " ".join(str(exc).split())[:300]
        return StoreError(f"job database {self.describe()}: {text}")

    def close(self) -> None:
        with self._lock:
            idle, self._idle = self._idle, []
        for db in idle:
            db.close()


def is_postgres_url(url: str) -> bool:
    return url.startswith(("postgresql://", "postgres://"))


def open_store(url: str | Path) -> JobStore:
    """A PostgreSQL store for a ``postgresql://`` URL, else a SQLite store at the path."""
    text = str(url)
    if is_postgres_url(text):
        return PostgresStore(text)
    return SqliteStore(text)


