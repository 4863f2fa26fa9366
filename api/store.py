"""The job store: accepted optimization jobs, durable before the 202 goes out, shared by every
replica of the service; the scenes keys uploaded; and the replicas' shared ticket secret and
redeemed tickets.

One schema (:data:`jobs`, :data:`job_runs`, …), stated once with SQLAlchemy Core, and one set of
queries over it, on SQLite (a file; WAL, fsync on commit) or PostgreSQL
(``EXCITE_DATABASE_URL=postgresql://…``: several replicas on one database, psycopg 3). Opening a
store migrates it (:data:`ADDED`: what each schema version added, from the one statement of the
schema; databases of servers before versioning are version 1).

A job moves ``queued → running → succeeded | failed | cancelled``. Each run of a job has an
``attempt`` number, and only the current attempt of a running job may write its outcome, so a
straggler never overwrites a re-run and a job ends once. Every count-then-write (a key's quotas,
a claim, a reclaim, a purge) is one transaction holding the write lock (``BEGIN IMMEDIATE`` on
SQLite, an advisory lock on PostgreSQL: per key for its quotas, one for the dispatchers). Runs
hold leases (:meth:`JobStore.claim`, :meth:`~JobStore.heartbeat`, :meth:`~JobStore.reclaim`);
retention and storage quotas are per key, never touching another key's jobs or scenes
(:meth:`JobStore.purge`); a scene is kept for the key that uploaded it alone.

Every failure of the database is a :class:`~api.errors.StoreError` naming the store and what is
wrong (full, read-only, corrupt, unreachable), logged once when the fault starts and once when
the database answers again.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import secrets as _secrets
import socket
import threading
import time
import uuid
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterator

import sqlalchemy as sa
from sqlalchemy.schema import CreateColumn

from excite.core import processes

from .errors import OverQuota, StoreError

log = logging.getLogger("excite.api")

FINAL = ("succeeded", "failed", "cancelled")
ACTIVE = ("queued", "running")
# what a finished job's downloads need of its request (GET …/maneuver): the rest is dropped
KEPT_REQUEST_KEYS = ("rig", "name", "origin")
OPEN_KEY = ""  # the key id of jobs made without authentication (an open server)

meta = sa.MetaData()
Seconds = sa.Double  # seconds since the epoch

jobs = sa.Table(
    "jobs", meta,
    sa.Column("id", sa.Text, primary_key=True),
    sa.Column("kind", sa.Text, nullable=False),
    sa.Column("status", sa.Text, nullable=False),
    sa.Column("request", sa.Text, nullable=False),
    sa.Column("progress", sa.Text),
    sa.Column("result", sa.Text),
    sa.Column("error", sa.Text),
    sa.Column("cancel_requested", sa.Integer, nullable=False, server_default="0"),
    sa.Column("attempt", sa.Integer, nullable=False, server_default="0"),
    sa.Column("created_at", Seconds, nullable=False),
    sa.Column("started_at", Seconds),
    sa.Column("finished_at", Seconds),
    sa.Column("updated_at", Seconds, nullable=False),
    sa.Column("key_id", sa.Text, nullable=False, server_default=""),
    sa.Column("owner", sa.Text, nullable=False, server_default=""),
    sa.Column("lease_owner", sa.Text),
    sa.Column("lease_expires", Seconds),
    sa.Column("size_bytes", sa.Integer, nullable=False, server_default="0"),
    sa.Index("jobs_status", "status", "created_at"),
    sa.Index("jobs_key_status", "key_id", "status"),
    sa.Index("jobs_key_started", "key_id", "started_at"),
    sa.Index("jobs_finished", "status", "finished_at"),
)
job_runs = sa.Table(
    "job_runs", meta,
    sa.Column("job_id", sa.Text, primary_key=True),
    sa.Column("attempt", sa.Integer, primary_key=True),
    sa.Column("replica", sa.Text, nullable=False),
    sa.Column("started_at", Seconds, nullable=False),
    sa.Column("finished_at", Seconds),
    sa.Column("outcome", sa.Text),
)
shared_secrets = sa.Table(
    "excite_secrets", meta,
    sa.Column("name", sa.Text, primary_key=True),
    sa.Column("value", sa.Text, nullable=False),
)
redeemed = sa.Table(
    "excite_tickets", meta,
    sa.Column("nonce", sa.Text, primary_key=True),
    sa.Column("expires_at", Seconds, nullable=False),
)
schema = sa.Table("excite_schema", meta, sa.Column("version", sa.Integer, nullable=False))
scenes = sa.Table(
    "scenes", meta,
    sa.Column("key_id", sa.Text, primary_key=True),
    sa.Column("digest", sa.Text, primary_key=True),  # the scene's (excite.scene.model.Scene.digest)
    sa.Column("name", sa.Text, nullable=False),  # the uploaded file's name (its suffix says how to read it)
    sa.Column("summary", sa.Text, nullable=False),  # what POST /v1/scenes answered, as JSON
    sa.Column("data", sa.LargeBinary, nullable=False),
    sa.Column("size_bytes", sa.Integer, nullable=False),
    sa.Column("created_at", Seconds, nullable=False),
    sa.Column("used_at", Seconds, nullable=False),
    sa.Index("scenes_key_used", "key_id", "used_at"),
)

# what each version added to version 1 (the jobs table's first columns): append, never edit
ADDED: dict[int, tuple[tuple[str, ...], tuple[sa.Table, ...]]] = {
    2: (("key_id", "owner", "lease_owner", "lease_expires", "size_bytes"), (job_runs,)),
    3: ((), (shared_secrets, redeemed)),
    4: ((), (scenes,)),
}
SCHEMA_VERSION = max(ADDED)
_VIEW = [c for c in jobs.c if c.name not in ("request", "size_bytes")]


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
    parts = holder.split("/")
    return (len(parts) == 4 and parts[0] == socket.gethostname() and parts[1] == boot_id()[:8]
            and parts[2].isdigit() and not processes.alive(int(parts[2])))


def _loads(text: str | None) -> Any:
    return None if text is None else json.loads(text)


def _current(job_id: str, attempt: int) -> Any:
    """Where the run ``attempt`` of the job ``job_id`` is its current one (the job is running)."""
    return (jobs.c.id == job_id) & (jobs.c.attempt == attempt) & (jobs.c.status == "running")


def _of_key(table: sa.Table, key_id: str | None) -> Any:
    """Where a row is ``key_id``'s (None: anyone's)."""
    return sa.true() if key_id is None else table.c.key_id == key_id


def _scene(key_id: str, digest: str) -> Any:
    return (scenes.c.key_id == key_id) & (scenes.c.digest == digest)


def is_postgres_url(url: str) -> bool:
    return url.startswith(("postgresql://", "postgres://"))


class JobStore:
    """The jobs at ``url``: a ``postgresql://`` URL, else the path of a SQLite file."""

    def __init__(self, url: str | Path, connect_timeout_s: float = 10.0):
        text = str(url)
        self.url = text
        self.postgres = is_postgres_url(text)
        if self.postgres:
            self.path = None
            driver = "postgresql+psycopg://" + text.split("://", 1)[1]
            self.engine = sa.create_engine(driver, pool_size=4, max_overflow=8, pool_pre_ping=True,
                                           pool_timeout=connect_timeout_s,
                                           connect_args={"connect_timeout": int(connect_timeout_s)})
        else:
            self.path = Path(text)
            if self.path.is_dir():
                raise StoreError(f"job database {self.path}: is a directory (give a file path)")
            self.engine = sa.create_engine(f"sqlite+pysqlite:///{self.path}", poolclass=sa.NullPool,
                                           connect_args={"timeout": 30, "isolation_level": None})
            sa.event.listen(self.engine, "connect", _sqlite_connect)
            sa.event.listen(self.engine, "begin", lambda conn: conn.exec_driver_sql("BEGIN IMMEDIATE"))
        self.fault: str | None = None  # the fault logged last, until the database answers again
        self._fault_lock = threading.Lock()
        self._opened = False  # a store that cannot be opened is the opener's error, not logged here
        self._migrate()
        self._opened = True

    def describe(self) -> str:
        if not self.postgres:
            return str(self.path)
        u = self.engine.url
        return f"postgresql {u.host or 'localhost'}:{u.port or 5432}/{u.database or ''}"

    def close(self) -> None:
        self.engine.dispose()

    # -- transactions -----------------------------------------------------------------------

    @contextmanager
    def _tx(self, lock: str | None = None) -> Iterator[sa.Connection]:
        """A transaction; ``lock`` names what it serialises (PostgreSQL: an advisory lock of
        that name; SQLite: every transaction holds the write lock)."""
        try:
            with self.engine.begin() as c:
                if lock is not None and self.postgres:
                    c.execute(sa.text("SELECT pg_advisory_xact_lock(:k)"),
                              {"k": int.from_bytes(hashlib.sha256(lock.encode()).digest()[:8], "big", signed=True)})
                yield c
        except StoreError:
            raise
        except sa.exc.IntegrityError as exc:  # a constraint said no (a ticket used twice): no fault
            raise self._fault(getattr(exc, "orig", None) or exc) from None
        except (sa.exc.DBAPIError, sa.exc.TimeoutError) as exc:
            fault = self._fault(getattr(exc, "orig", None) or exc)
            with self._fault_lock:
                if self._opened and str(fault) != self.fault:
                    log.error("job store fault: %s", fault)
                self.fault = str(fault)
            raise fault from None
        if self.fault is not None:
            with self._fault_lock:
                if self.fault is not None:
                    log.warning("job store answers again")
                self.fault = None

    def _fault(self, exc: BaseException) -> StoreError:
        text = " ".join(str(exc).split())[:300]
        if self.postgres:
            return StoreError(f"job database {self.describe()}: {text}")
        low, folder = text.lower(), self.path.parent
        if "disk is full" in low or "disk i/o" in low:
            why = f"the disk is full or failing ({text}); free space on {folder}"
        elif "readonly" in low or "read-only" in low or (
                "unable to open" in low and folder.is_dir() and not os.access(folder, os.W_OK)):
            why = (f"cannot write ({text}): the folder {folder} or the file is read-only; the server "
                   "needs write access to both (SQLite writes its journal beside the file)")
        elif "not a database" in low or "malformed" in low or "no such table" in low or "no such column" in low:
            why = f"cannot be used ({text}); move it away or set EXCITE_DB_PATH to another file"
        elif "locked" in low or "busy" in low:
            why = f"is busy ({text}); another process holds it"
        else:
            why = f"failed ({text})"
        return StoreError(f"job database {self.path}: {why}")

    def _migrate(self) -> None:
        with self._tx("migrate") as c:
            schema.create(c, checkfirst=True)
            current = c.execute(sa.select(sa.func.max(schema.c.version))).scalar()
            if current is None:
                current = 1 if sa.inspect(c).has_table("jobs") else 0
            if current > SCHEMA_VERSION:
                raise StoreError(f"job database {self.describe()}: schema version {current} is newer "
                                 f"than this server's ({SCHEMA_VERSION}); upgrade the server")
            if current == 0:
                meta.create_all(c)
                c.execute(schema.insert().values(version=SCHEMA_VERSION))
            for version in range(current + 1, SCHEMA_VERSION + 1) if current else ():
                columns, tables = ADDED[version]
                for name in columns:
                    column = CreateColumn(jobs.c[name]).compile(dialect=c.dialect)
                    c.execute(sa.text(f"ALTER TABLE jobs ADD COLUMN {column}"))
                for table in tables:
                    table.create(c, checkfirst=True)
                for index in jobs.indexes:
                    index.create(c, checkfirst=True)
                if "size_bytes" in columns:
                    c.execute(jobs.update().values(size_bytes=sa.func.length(jobs.c.request) + sum(
                        sa.func.coalesce(sa.func.length(jobs.c[k]), 0) for k in ("result", "error", "progress"))))
                c.execute(schema.insert().values(version=version))
            # a database of something else that happens to have a jobs table
            c.execute(sa.select(*jobs.c).limit(1)).fetchall()

    def ping(self) -> None:
        """Raises :class:`StoreError` when the database does not answer a read."""
        with self._tx() as c:
            c.execute(sa.select(sa.func.count()).select_from(schema)).scalar()

    # -- requests side ----------------------------------------------------------------------

    def create(self, kind: str, request: dict[str, Any], key_id: str = OPEN_KEY, owner: str = "",
               max_active: int | None = None, max_bytes: int | None = None) -> str:
        """Persist a queued job (committed and synced on return) and return its id. In the same
        transaction: :class:`OverQuota` when the key has ``max_active`` jobs queued or running, or
        when its unfinished jobs and this one would hold more than ``max_bytes``; the key's own
        oldest finished jobs are deleted to make room."""
        text = json.dumps(request)
        now = time.time()
        job_id = uuid.uuid4().hex
        with self._tx(f"key:{key_id}") as c:
            self._room(c, key_id, "request", len(text), max_bytes, max_active)
            c.execute(jobs.insert().values(id=job_id, kind=kind, status="queued", request=text,
                                           created_at=now, updated_at=now, key_id=key_id, owner=owner,
                                           size_bytes=len(text)))
            if max_bytes is not None:
                self._trim(c, key_id, max_bytes)
        return job_id

    @staticmethod
    def _room(c: sa.Connection, key_id: str, what: str, size: int, max_bytes: int | None,
              max_active: int | None = None) -> None:  # the quota check of create and put_scene
        active, held = c.execute(sa.select(sa.func.count(), sa.func.coalesce(sa.func.sum(jobs.c.size_bytes), 0))
                                 .where(jobs.c.key_id == key_id, jobs.c.status.in_(ACTIVE))).one()
        if max_active is not None and active >= max_active:
            raise OverQuota(f"the key {key_id} has {active} jobs queued or running already "
                            f"(its quota: {max_active}); retry when one has finished")
        if max_bytes is not None and held + size > max_bytes:
            raise OverQuota(f"the key {key_id}'s unfinished jobs hold {held} bytes; this {what} "
                            f"({size} bytes) would exceed its storage quota of {max_bytes} bytes")

    def get(self, job_id: str, key_id: str | None = None) -> dict[str, Any] | None:
        """The job (without its request), or None; with ``key_id``, only a job of that key."""
        with self._tx() as c:
            row = c.execute(sa.select(*_VIEW).where(jobs.c.id == job_id, _of_key(jobs, key_id))).mappings().first()
        return None if row is None else {**row, **{k: _loads(row[k]) for k in ("progress", "result", "error")}}

    def request_of(self, job_id: str, attempt: int | None = None) -> dict[str, Any] | None:
        """The job's request; with ``attempt``, only while that run of it is the current one."""
        q = sa.select(jobs.c.request).where(jobs.c.id == job_id if attempt is None else _current(job_id, attempt))
        with self._tx() as c:
            return _loads(c.execute(q).scalar())

    def cancel(self, job_id: str, key_id: str | None = None) -> str | None:
        """Cancel a queued job at once, flag a running one; returns the status after, or None
        (no such job, or none of ``key_id``'s)."""
        now = time.time()
        with self._tx("claim") as c:
            status = c.execute(sa.select(jobs.c.status).where(jobs.c.id == job_id, _of_key(jobs, key_id))).scalar()
            if status == "queued":
                c.execute(jobs.update().where(jobs.c.id == job_id).values(
                    status="cancelled", cancel_requested=1, finished_at=now, updated_at=now))
                status = "cancelled"
            elif status == "running":
                c.execute(jobs.update().where(jobs.c.id == job_id).values(cancel_requested=1, updated_at=now))
        return status

    def counts(self) -> dict[str, int]:
        with self._tx() as c:
            rows = c.execute(sa.select(jobs.c.status, sa.func.count()).group_by(jobs.c.status)).all()
        return {s: n for s, n in rows}

    def runs(self, job_id: str) -> list[dict[str, Any]]:
        """Every run of a job: attempt, replica, start, end and outcome."""
        with self._tx() as c:
            rows = c.execute(sa.select(job_runs).where(job_runs.c.job_id == job_id)
                             .order_by(job_runs.c.attempt)).mappings().all()
        return [dict(r) for r in rows]

    # -- dispatcher side --------------------------------------------------------------------

    def claim(self, replica: str, lease_s: float) -> tuple[str, int] | None:
        """The next queued job, now running under a new attempt and a lease of ``lease_s`` held by
        ``replica``: of the key with the fewest running jobs, then the one served longest ago, the
        oldest job."""
        now = time.time()
        with self._tx("claim") as c:
            waiting = c.execute(sa.select(jobs.c.key_id, sa.func.min(jobs.c.created_at))
                                .where(jobs.c.status == "queued").group_by(jobs.c.key_id)).all()
            if not waiting:
                return None
            running = dict(c.execute(sa.select(jobs.c.key_id, sa.func.count()).where(jobs.c.status == "running")
                                     .group_by(jobs.c.key_id)).all())
            last = dict(c.execute(sa.select(jobs.c.key_id, sa.func.max(jobs.c.started_at)).group_by(jobs.c.key_id)).all())
            key_id = min((running.get(k, 0), last.get(k) or 0.0, first, k) for k, first in waiting)[3]
            job_id, attempt = c.execute(sa.select(jobs.c.id, jobs.c.attempt).where(
                jobs.c.key_id == key_id, jobs.c.status == "queued").order_by(jobs.c.created_at).limit(1)).one()
            attempt += 1
            c.execute(jobs.update().where(jobs.c.id == job_id).values(
                status="running", attempt=attempt, started_at=now, updated_at=now, lease_owner=replica,
                lease_expires=now + lease_s))
            c.execute(job_runs.insert().values(job_id=job_id, attempt=attempt, replica=replica, started_at=now))
        return job_id, attempt

    def heartbeat(self, replica: str, lease_s: float, held: set[tuple[str, int]]) -> set[tuple[str, int]]:
        """Renew the leases of the runs ``held`` (that ``replica`` really runs); returns those
        still its own (a run missing from the answer was lost: another replica may run it)."""
        now = time.time()
        out = set()
        with self._tx() as c:
            for job_id, attempt in held:
                if c.execute(jobs.update().where(_current(job_id, attempt), jobs.c.lease_owner == replica)
                             .values(lease_expires=now + lease_s)).rowcount:
                    out.add((job_id, attempt))
        return out

    def reclaim(self, replica: str) -> list[str]:
        """Running jobs whose lease expired, or whose holder is a dead process of this host, go
        back to the queue (cancelled if asked); returns the ids re-queued. A live lease of
        another replica is never touched."""
        now = time.time()
        with self._tx("claim") as c:
            rows = c.execute(sa.select(jobs.c.id, jobs.c.attempt, jobs.c.lease_owner, jobs.c.lease_expires,
                                       jobs.c.cancel_requested).where(
                jobs.c.status == "running",
                sa.or_(jobs.c.lease_owner.is_(None), jobs.c.lease_owner != replica))).all()
            out = []
            for job_id, attempt, holder, expires, cancel in rows:
                if holder is not None and (expires or 0) >= now and not local_holder_dead(holder):
                    continue
                this = _current(job_id, attempt)
                self._ended(c, job_id, attempt, now, "lost")
                if cancel:
                    c.execute(jobs.update().where(this).values(status="cancelled", finished_at=now,
                                                               updated_at=now, lease_owner=None))
                else:
                    c.execute(jobs.update().where(this).values(status="queued", updated_at=now,
                                                               lease_owner=None, lease_expires=None))
                    out.append(job_id)
        return out

    def release(self, job_id: str, attempt: int) -> None:
        """A run stopped by this server's shutdown: back to the queue for the next server."""
        now = time.time()
        with self._tx() as c:
            if c.execute(jobs.update().where(_current(job_id, attempt)).values(
                    status="queued", updated_at=now, lease_owner=None, lease_expires=None)).rowcount:
                self._ended(c, job_id, attempt, now, "released")

    def cancel_requested(self, replica: str) -> set[tuple[str, int]]:
        """(id, attempt) of ``replica``'s running jobs asked to stop."""
        with self._tx() as c:
            rows = c.execute(sa.select(jobs.c.id, jobs.c.attempt).where(
                jobs.c.status == "running", jobs.c.cancel_requested == 1, jobs.c.lease_owner == replica)).all()
        return {(i, a) for i, a in rows}

    def progress(self, job_id: str, attempt: int, progress: dict[str, Any]) -> None:
        with self._tx() as c:
            c.execute(jobs.update().where(_current(job_id, attempt))
                      .values(progress=json.dumps(progress), updated_at=time.time()))

    def finish(self, job_id: str, attempt: int, status: str, result: dict[str, Any] | None = None,
               error: dict[str, Any] | None = None, progress: dict[str, Any] | None = None) -> bool:
        """The run's outcome, written once (only by the current attempt of a running job): False
        when that run is no longer current. The stored request shrinks to what the downloads need."""
        if status not in FINAL:
            raise ValueError(f"not a final status: {status!r}")
        now = time.time()
        res = None if result is None else json.dumps(result)
        err = None if error is None else json.dumps(error)
        this = _current(job_id, attempt)
        with self._tx() as c:
            row = c.execute(sa.select(jobs.c.request, jobs.c.progress).where(this)).first()
            if row is None:
                return False
            req = json.dumps({k: v for k, v in json.loads(row.request).items() if k in KEPT_REQUEST_KEYS})
            prog = row.progress if progress is None else json.dumps(progress)
            c.execute(jobs.update().where(this).values(
                status=status, result=res, error=err, request=req, progress=prog, finished_at=now,
                updated_at=now, lease_owner=None, size_bytes=sum(len(t) for t in (req, res, err, prog) if t)))
            self._ended(c, job_id, attempt, now, status)
        return True

    @staticmethod
    def _ended(c: sa.Connection, job_id: str, attempt: int, now: float, outcome: str) -> None:
        c.execute(job_runs.update().where(job_runs.c.job_id == job_id, job_runs.c.attempt == attempt,
                                          job_runs.c.finished_at.is_(None)).values(finished_at=now, outcome=outcome))

    def purge(self, max_age_s: float, max_bytes: Callable[[str], int]) -> int:
        """Per key: delete its finished jobs older than ``max_age_s`` and its scenes unused for as
        long, and while its jobs and scenes hold more than ``max_bytes(key_id)``, its oldest finished
        jobs and least recently used scenes; returns how many were deleted."""
        deleted = 0
        before = time.time() - max_age_s
        with self._tx("claim") as c:
            old = c.execute(sa.select(jobs.c.id).where(jobs.c.status.in_(FINAL),
                                                       jobs.c.finished_at < before)).scalars().all()
            deleted += self._delete(c, old)
            deleted += c.execute(scenes.delete().where(scenes.c.used_at < before)).rowcount
            keys = set(c.execute(sa.select(jobs.c.key_id).distinct()).scalars().all())
            keys |= set(c.execute(sa.select(scenes.c.key_id).distinct()).scalars().all())
            for key_id in sorted(keys):
                deleted += self._trim(c, key_id, max_bytes(key_id))
            c.execute(redeemed.delete().where(redeemed.c.expires_at < time.time()))
        return deleted

    def _trim(self, c: sa.Connection, key_id: str, max_bytes: int) -> int:
        """While the key's jobs and scenes hold more than ``max_bytes``: delete its oldest finished
        job or least recently used scene, whichever is older."""
        total = sum(c.execute(sa.select(sa.func.coalesce(sa.func.sum(t.c.size_bytes), 0)).where(
            t.c.key_id == key_id)).scalar() for t in (jobs, scenes))
        if total <= max_bytes:
            return 0
        done = c.execute(sa.select(jobs.c.finished_at, jobs.c.id, jobs.c.size_bytes).where(
            jobs.c.key_id == key_id, jobs.c.status.in_(FINAL))).all()
        kept = c.execute(sa.select(scenes.c.used_at, scenes.c.digest, scenes.c.size_bytes).where(
            scenes.c.key_id == key_id)).all()
        candidates = sorted([(t or 0.0, 0, i, n) for t, i, n in done] + [(t, 1, d, n) for t, d, n in kept])
        gone_jobs, gone_scenes = [], []
        for _, is_scene, ident, size in candidates:
            if total <= max_bytes:
                break
            (gone_scenes if is_scene else gone_jobs).append(ident)
            total -= size
        for i in range(0, len(gone_scenes), 500):
            c.execute(scenes.delete().where(scenes.c.key_id == key_id, scenes.c.digest.in_(gone_scenes[i:i + 500])))
        return self._delete(c, gone_jobs) + len(gone_scenes)

    @staticmethod
    def _delete(c: sa.Connection, ids: list[str]) -> int:
        n = 0
        for i in range(0, len(ids), 500):
            chunk = ids[i:i + 500]
            n += c.execute(jobs.delete().where(jobs.c.id.in_(chunk))).rowcount
            c.execute(job_runs.delete().where(job_runs.c.job_id.in_(chunk)))
        return n

    # -- scenes -------------------------------------------------------------------------------

    def put_scene(self, key_id: str, digest: str, name: str, summary: dict[str, Any], data: bytes,
                  max_bytes: int | None = None) -> bool:
        """Keep the scene file ``data`` (named ``name``) of ``key_id`` under the scene's ``digest``
        with its ``summary``; False when the key has it already (then only marked used). In the same
        transaction: :class:`OverQuota` when the key's unfinished jobs leave no room for it within
        ``max_bytes``; the key's oldest finished jobs and least recently used scenes make room."""
        now = time.time()
        with self._tx(f"key:{key_id}") as c:
            if c.execute(scenes.update().where(_scene(key_id, digest)).values(used_at=now)).rowcount:
                return False
            self._room(c, key_id, "scene", len(data), max_bytes)
            c.execute(scenes.insert().values(key_id=key_id, digest=digest, name=name, summary=json.dumps(summary),
                                             data=data, size_bytes=len(data), created_at=now, used_at=now))
            if max_bytes is not None:
                self._trim(c, key_id, max_bytes)
        return True

    def scene(self, key_id: str, digest: str) -> tuple[str, bytes] | None:
        """The name and bytes of ``key_id``'s scene ``digest`` (marked used), or None."""
        with self._tx() as c:
            row = c.execute(sa.select(scenes.c.name, scenes.c.data).where(_scene(key_id, digest))).first()
            if row is not None:
                c.execute(scenes.update().where(_scene(key_id, digest)).values(used_at=time.time()))
        return None if row is None else (row.name, bytes(row.data))

    def scene_summaries(self, key_id: str, digest: str | None = None) -> list[dict[str, Any]]:
        """The key's scenes (or its scene ``digest``), most recently used first: each one's summary
        with its digest, name, size and times."""
        q = sa.select(scenes.c.digest, scenes.c.name, scenes.c.summary, scenes.c.size_bytes, scenes.c.created_at,
                      scenes.c.used_at).where(scenes.c.key_id == key_id if digest is None else _scene(key_id, digest))
        with self._tx() as c:
            rows = c.execute(q.order_by(scenes.c.used_at.desc())).mappings().all()
        return [{**json.loads(r["summary"]), "digest": r["digest"], "name": r["name"], "size_bytes": r["size_bytes"],
                 "created_at": r["created_at"], "used_at": r["used_at"]} for r in rows]

    def delete_scene(self, key_id: str, digest: str) -> bool:
        """Delete ``key_id``'s scene ``digest``; False when it has none."""
        with self._tx(f"key:{key_id}") as c:
            return bool(c.execute(scenes.delete().where(_scene(key_id, digest))).rowcount)

    # -- tickets ------------------------------------------------------------------------------

    def secret(self, name: str = "ticket") -> bytes:
        """A random secret shared by every replica of this store (made by the first to ask)."""
        with self._tx(f"secret:{name}") as c:
            value = c.execute(sa.select(shared_secrets.c.value).where(shared_secrets.c.name == name)).scalar()
            if value is None:
                value = _secrets.token_hex(32)
                c.execute(shared_secrets.insert().values(name=name, value=value))
        return bytes.fromhex(value)

    def redeem(self, nonce: str, expires_at: float) -> bool:
        """Whether the ticket ``nonce`` is redeemed now for the first time (on any replica)."""
        try:
            with self._tx() as c:
                c.execute(redeemed.insert().values(nonce=nonce, expires_at=expires_at))
        except StoreError as exc:
            if "unique" in str(exc).lower() or "duplicate" in str(exc).lower():
                return False
            raise
        return True


def _sqlite_connect(dbapi_connection: Any, _record: Any) -> None:
    dbapi_connection.execute("PRAGMA journal_mode=WAL")
    dbapi_connection.execute("PRAGMA synchronous=FULL")
