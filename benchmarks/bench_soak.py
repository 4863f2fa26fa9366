"""Soak the service: mixed traffic from 8 clients on loopback for 10 minutes, hostile requests
included, optimization jobs submitted and cancelled. The service must answer no 5xx at all,
leave no process behind, and the server process's memory at the end must be within 20 % of the
start.

Starts ``excite serve`` on a free 127.0.0.1 port (its own job database in a temporary folder;
one job worker, scoring workers as configured) and runs ``--clients`` threads. Each picks a
request by weight:

- valid scores: a 90 s figure-eight as a control profile, and a 10-minute drive as TUM text;
- a plot, a batch of three routes, a maneuver job (the real optimizer, short budget) polled to
  its end or cancelled (queued or running; half of them), a /v1/live session of 20 s of poses;
- reads: rigs, health, metrics, a job that does not exist;
- hostile: absurd numbers (a gyro density of 1e-308, an IMU rate of 1e308, coordinates at 1e300,
  limits at 1e308), a rig nested 950 levels deep, a rig with 500 sensors, a 3-knot control
  route over 10⁶ s, malformed JSON, a method not allowed, an MCAP whose zstd chunk declares
  192 MiB of zeros and a GeoJSON lot that crosses itself (both 422), a client that announces a
  body and stops sending, and one that sends its headers a byte every 0.5 s (both must get 408).

``--flood`` runs the soak on a server with two API keys: the clients above use the *quiet*
key, and a *flooding* key sends an hour-long route three times a second without waiting for the
answers (within its rate quota of 3 per second; at most 32 in flight) during every other
``--flood-period-s``. A probe of the quiet key scores a 20 s route every second throughout; its
median latency while the flood runs, against its median while it does not (same traffic of its
own, same machine), is the figure: within 3× passes. The flood's answers must be 200 or 429
(refused at once, never a 503 at the time limit).

A valid request may also be refused at once with 429 when the scoring workers cannot finish it
within the time limit (back-pressure, not an error): the client then waits the Retry-After it
was given. The 429s are counted and their latency printed.

The memory gated is the resident set of the server process, read from /proc once the service
is warm and again at the end after in-flight jobs have finished: the server holds every request,
session and job record, so it is where a leak would accumulate. The scoring workers (forkserver
and workers) and the whole process tree are read and reported apart, every 30 s, but not gated:
a worker holds one task's drive while it runs and is replaced once it grows past
``worker_recycle_mb``, so the pool's reading at any moment depends on which tasks are in flight
(hour-long routes under ``--flood``), not on how long the service has run. Every process below
the server is noted every 2 s while the soak runs; at the end none of them may have outlived the
server's shutdown, nor have been orphaned (re-parented away from the server) before it. Prints
the counts per kind and status, p50/p99 latency of valid scores, the memory and the processes;
exits 1 on any 5xx, an unexpected status, a process left behind, or the server process's memory
growing over 20 %.

The figures are written to ``benchmarks/results/soak.json`` (``soak_flood.json`` with ``--flood``).

    python benchmarks/bench_soak.py [--duration-s 600] [--clients 8] [--seed 0] [--flood]
"""

from __future__ import annotations

import argparse
import collections
import json
import math
import random
import socket
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_api import machine, pct, route_text  # noqa: E402
from results import Session, spread  # noqa: E402
from servers import LiveServer, write_keys  # noqa: E402

FIGURE_EIGHT = {"control": {"t_s": [0, 10, 20, 30, 40, 50, 60, 70, 80, 90],
                            "speed_mps": [0, 4, 6, 6, 5, 6, 6, 5, 3, 0],
                            "curvature_1pm": [0, 0.1, 0.12, -0.1, -0.12, 0.1, 0.12, -0.1, -0.05, 0]}}
LOOP = {"waypoints": [[0, 0], [30, 0], [30, 20], [0, 20], [0, 1]]}
SHORT = {"control": {"t_s": [0, 10, 20], "speed_mps": [0, 5, 0], "curvature_1pm": [0, 0.1, 0]}}
HOUR = {"control": {"t_s": [0, 1200, 2400, 3600], "speed_mps": [5, 9, 7, 5],
                    "curvature_1pm": [0.02, -0.03, 0.01, 0.02]}}
OK = {200, 429}  # a valid request is served, or refused at once as overloaded (back-pressure)


def _start_time(pid: int) -> int | None:
    try:
        return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[19])
    except (OSError, IndexError, ValueError):
        return None


def _zombie(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except (OSError, IndexError):
        return False


def tree(pid: int) -> dict[int, int]:
    """pid → parent of every live process below ``pid``."""
    parents = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if fields[0] != "Z":
                parents[int(d.name)] = int(fields[1])
    out, frontier = {}, {pid}
    while frontier:
        frontier = {p for p, pp in parents.items() if pp in frontier and p not in out}
        out.update({p: parents[p] for p in frontier})
    return out


def rss_mb(pids) -> float:
    total = 0.0
    for p in pids:
        try:
            total += int(Path(f"/proc/{p}/statm").read_text().split()[1]) * 4096 / 2**20
        except (OSError, IndexError, ValueError):
            pass
    return total


class Processes:
    """Every process seen below the server (pid and start time), sampled until stopped, and the
    resident memory of the server, of its scoring pool and of its whole tree every 30 s."""

    def __init__(self, server: int):
        self.server, self.seen = server, set()
        self.memory: list[tuple[float, float, float, float]] = []  # (s, server, pool, tree) [MiB]
        self.t0 = time.monotonic()
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True)

    def sample(self) -> None:
        for p in tree(self.server):
            t = _start_time(p)
            if t is not None:
                self.seen.add((p, t))

    def run(self) -> None:
        last = -math.inf
        while not self.stop.wait(2.0):
            self.sample()
            now = time.monotonic()
            if now - last >= 30:
                last = now
                self.memory.append((now - self.t0, rss_mb([self.server]), rss_mb(workers_of(self.server)),
                                    tree_rss_mb(self.server)))

    def alive(self) -> list[int]:
        """Those still running (a zombie has ended: only its parent has not reaped it yet, and a
        container's init may never reap what was re-parented to it)."""
        return [p for p, t in self.seen if _start_time(p) == t and not _zombie(p)]

    def orphans(self) -> list[int]:
        below = set(tree(self.server))
        return [p for p in self.alive() if p not in below]


def workers_of(server: int) -> list[int]:
    """The scoring pool: the forkserver (a child of the server running multiprocessing's
    forkserver) and the workers it forked."""
    t = tree(server)
    out = []
    for p, parent in t.items():
        try:
            cmd = Path(f"/proc/{p}/cmdline").read_bytes()
        except OSError:
            continue
        if b"forkserver" in cmd or (parent != server and b"forkserver" in Path(f"/proc/{parent}/cmdline").read_bytes()):
            out.append(p)
    return out


def tree_rss_mb(pid: int) -> float:
    """Resident memory of ``pid`` and every process below it [MiB]."""
    parents, rss = {}, {}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text().rsplit(")", 1)[1].split()
            statm = (d / "statm").read_text().split()
        except OSError:
            continue
        parents[int(d.name)] = int(stat[1])
        rss[int(d.name)] = int(statm[1]) * 4096 / 2**20
    tree, frontier = {pid}, {pid}
    while frontier:
        frontier = {p for p, pp in parents.items() if pp in frontier and p not in tree}
        tree |= frontier
    return sum(rss.get(p, 0.0) for p in tree)


def inline_rig(**imu: float) -> dict:
    from excite.rig.config import load_rig

    data = json.loads(json.dumps(load_rig("robotaxi").config.model_dump()))
    data["imu"].update(imu)
    return data


def zstd_bomb_mcap(declared: int) -> bytes:
    """An MCAP without a summary whose one zstd chunk declares ``declared`` bytes of zeros."""
    import struct

    try:
        from compression import zstd
    except ImportError:
        from backports import zstd
    c = zstd.ZstdCompressor()
    data = b"".join(c.compress(bytes(64 << 20)) for _ in range(declared >> 26)) + c.flush()

    def rec(op: int, body: bytes) -> bytes:
        return struct.pack("<BQ", op, len(body)) + body

    def string(text: str) -> bytes:
        return struct.pack("<I", len(text)) + text.encode()

    chunk = struct.pack("<QQQI", 0, 10**9, declared, 0) + string("zstd") + struct.pack("<Q", len(data)) + data
    return (b"\x89MCAP0\r\n" + rec(0x01, string("ros2") + string("soak")) + rec(0x06, chunk)
            + rec(0x0F, struct.pack("<I", 0)) + rec(0x02, struct.pack("<QQI", 0, 0, 0)) + b"\x89MCAP0\r\n")


class Soak:
    def __init__(self, srv: LiveServer, tum_10min: str, seed: int, key: str | None = None):
        self.srv, self.tum = srv, tum_10min
        self.headers = {"X-API-Key": key} if key else {}
        self.raw_auth = f"X-API-Key: {key}\r\n".encode() if key else b""
        self.rng = random.Random(seed)
        self.lock = threading.Lock()
        self.counts: collections.Counter = collections.Counter()
        self.latency: dict[str, list[float]] = collections.defaultdict(list)
        self.unexpected: list[str] = []
        self.shed_latency: list[float] = []  # how fast a 429 came back
        self.details: list[str] = []  # the problem documents of 5xx answers
        rig = inline_rig()
        many = dict(rig, sensors=[dict(rig["sensors"][0], name=f"s{i}") for i in range(500)])
        deep = '{"route": {"waypoints": [[0, 0], [30, 0], [30, 20]]}, "rig": ' + '{"a": ' * 950 + "1" + "}" * 951
        self.hostile = [
            ("gyro 1e-308", "POST", "/v1/score", {"route": LOOP, "rig": inline_rig(gyroscope_noise_density=1e-308)}, {422}),
            ("imu rate 1e308", "POST", "/v1/score", {"route": LOOP, "rig": inline_rig(update_rate=1e308)}, {422}),
            ("coords 1e300", "POST", "/v1/score", {"route": {"waypoints": [[0, 0], [1e300, 0]]}}, {422}),
            ("limits 1e308", "POST", "/v1/score", {"route": LOOP, "limits": {"speed_max_mps": 1e308}}, {422}),
            ("500 sensors", "POST", "/v1/score", {"route": LOOP, "rig": many}, {422}),
            ("control over 1e6 s", "POST", "/v1/score", {"route": {"format": "control_csv", "text":
                "t_s,speed_mps,curvature_1pm\n0,0,0\n500000,5,0.1\n1000000,0,0\n"}}, {422}),
            ("nested 950", "POST", "/v1/score", deep.encode(), {422}),
            ("malformed JSON", "POST", "/v1/score", b'{"route": ', {422}),
            ("method not allowed", "PUT", "/v1/score", {}, {405}),
            ("maneuver 1e308 s", "POST", "/v1/maneuvers", {"duration_s": 1e308}, {422}),
            ("lot crossing itself", "POST", "/v1/maneuvers", {"lot": {"type": "FeatureCollection",
                "properties": {"crs": "local"}, "features": [{"type": "Feature", "properties": {}, "geometry": {
                    "type": "Polygon", "coordinates": [[[0, 0], [60, 60], [60, 0], [0, 60], [0, 0]]]}}]}}, {422}),
        ]
        self.bomb = zstd_bomb_mcap(192 << 20)

    def record(self, kind: str, status: int, seconds: float, expected: set[int]) -> None:
        with self.lock:
            self.counts[(kind, status)] += 1
            if status < 300 and status in expected:
                self.latency[kind].append(seconds)
            if status == 429:
                self.shed_latency.append(seconds)
            elif status >= 500 or status not in expected:
                self.unexpected.append(f"{kind}: {status}")

    def call(self, c: httpx.Client, kind: str, method: str, path: str, body, expected: set[int]):
        t0 = time.perf_counter()
        try:
            if isinstance(body, bytes):
                r = c.request(method, path, content=body, headers={"content-type": "application/json"})
            elif method in ("GET", "DELETE"):
                r = c.request(method, path)
            else:
                r = c.request(method, path, json=body)
            status = r.status_code
        except httpx.HTTPError as exc:
            status, r = 599, None
            with self.lock:
                self.unexpected.append(f"{kind}: {type(exc).__name__}")
        self.record(kind, status, time.perf_counter() - t0, expected)
        if r is not None and status >= 500:
            with self.lock:
                self.details.append(f"{kind}: {status} after {time.perf_counter() - t0:.1f} s: {r.text[:200]}")
        if status == 429:  # back-pressure: a well-behaved client waits as told
            time.sleep(float(r.headers.get("retry-after", "1")))
        return r

    def slow_body(self) -> None:
        t0 = time.perf_counter()
        status = 599
        try:
            with socket.create_connection(("127.0.0.1", self.srv.port), timeout=60) as s:
                s.sendall(b"POST /v1/score HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                          + self.raw_auth + b"Content-Length: 5000\r\n\r\n{\"route\": ")
                data = s.recv(4096)
                if data.startswith(b"HTTP/1.1 "):
                    status = int(data[9:12])
        except OSError:
            pass
        self.record("slow body", status, time.perf_counter() - t0, {408})

    def slow_headers(self) -> None:
        """Headers sent a byte every 0.5 s: the server must answer 408 and disconnect."""
        t0 = time.perf_counter()
        status = 599
        try:
            with socket.create_connection(("127.0.0.1", self.srv.port), timeout=60) as s:
                s.settimeout(0.5)
                s.sendall(b"POST /v1/score HTTP/1.1\r\n")
                for byte in b"Host: 127.0.0.1\r\nContent-Type: application/json\r\n" * 20:
                    try:
                        s.sendall(bytes([byte]))
                        data = s.recv(4096)
                    except socket.timeout:
                        continue
                    if data.startswith(b"HTTP/1.1 "):
                        status = int(data[9:12])
                    break
        except OSError:
            pass
        self.record("slow headers", status, time.perf_counter() - t0, {408})

    def job(self, c: httpx.Client) -> None:
        r = self.call(c, "maneuver job", "POST", "/v1/maneuvers",
                      {"duration_s": 30, "time_budget_s": 2, "n_random": 4}, {202})
        if r is None or r.status_code != 202:
            return
        loc = r.headers["location"]
        cancel = self.rng.random() < 0.5
        if cancel and self.rng.random() < 0.3:  # at once: usually still queued
            self.call(c, "job cancel", "DELETE", loc, None, {200, 202, 409})
            cancel = False
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline:
            g = self.call(c, "job poll", "GET", loc, None, {200})
            if g is None or g.status_code != 200 or g.json()["status"] in ("succeeded", "failed", "cancelled"):
                return
            if cancel:
                self.call(c, "job cancel", "DELETE", loc, None, {200, 202, 409})
                cancel = False
            time.sleep(1.0)

    def live(self) -> None:
        """A 20 s drive streamed to /v1/live: started, updates, final."""
        from websockets.sync.client import connect

        t0 = time.perf_counter()
        status = 599
        try:
            with connect(f"ws://127.0.0.1:{self.srv.port}/v1/live", open_timeout=60,
                         additional_headers=self.headers) as ws:
                ws.send(json.dumps({"type": "start", "rig": "robotaxi"}))
                first = json.loads(ws.recv(timeout=60))
                if first["type"] == "error":
                    status = first["problem"]["status"]
                else:
                    poses = [[0.1 * i, 0.5 * i, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0] for i in range(200)]
                    ws.send(json.dumps({"type": "poses", "poses": poses}))
                    ws.send(json.dumps({"type": "end"}))
                    while True:
                        msg = json.loads(ws.recv(timeout=120))
                        if msg["type"] in ("final", "error"):
                            status = 200 if msg["type"] == "final" else msg["problem"]["status"]
                            break
        except Exception as exc:  # a closed or refused socket
            with self.lock:
                self.unexpected.append(f"live: {type(exc).__name__}: {str(exc)[:100]}")
        self.record("live session", status, time.perf_counter() - t0, {200, 503})

    def client(self, stop_at: float, seed: int) -> None:
        rng = random.Random(seed)
        kinds = ["score 90 s", "score 10 min", "plot", "batch", "job", "read", "hostile", "slow body",
                 "slow headers", "bag bomb", "live"]
        weights = [30, 12, 4, 4, 4, 10, 16, 1, 1, 1, 1]
        with self.srv.client(timeout=120, headers=self.headers) as c:
            while time.monotonic() < stop_at:
                kind = rng.choices(kinds, weights)[0]
                if kind == "score 90 s":
                    self.call(c, kind, "POST", "/v1/score", {"route": FIGURE_EIGHT}, OK)
                elif kind == "score 10 min":
                    self.call(c, kind, "POST", "/v1/score", {"route": {"format": "tum", "text": self.tum}}, OK)
                elif kind == "plot":
                    self.call(c, kind, "POST", "/v1/score/plot", {"route": FIGURE_EIGHT}, OK)
                elif kind == "batch":
                    self.call(c, kind, "POST", "/v1/batch", {"routes": [FIGURE_EIGHT, LOOP, {"waypoints": [[0, 0], [0, 0]]}]}, OK)
                elif kind == "job":
                    self.job(c)
                elif kind == "read":
                    path, expected = rng.choice([("/v1/rigs", {200}), ("/healthz", {200}), ("/readyz", {200}),
                                                 ("/metrics", {200}), ("/v1/jobs/0123456789abcdef", {404})])
                    self.call(c, "read " + path, "GET", path, None, expected)
                elif kind == "hostile":
                    name, method, path, body, expected = rng.choice(self.hostile)
                    self.call(c, "hostile: " + name, method, path, body, expected)
                elif kind == "slow body":
                    self.slow_body()
                elif kind == "bag bomb":
                    t0 = time.perf_counter()
                    r = c.post("/v1/score/bag", files={"bag": ("bomb.mcap", self.bomb, "application/octet-stream")},
                               data={"topic": "/odom"}, headers={"X-Excite-Client": "soak"})
                    self.record("hostile: bag bomb", r.status_code, time.perf_counter() - t0, {422, 429})
                elif kind == "live":
                    self.live()
                else:
                    self.slow_headers()


class Flood:
    """The flooding key (an hour-long route three times a second, not waiting for answers, during every other
    ``period_s``) and the quiet key's probe (a 20 s route every second, its latency tagged by
    whether the flood was on)."""

    def __init__(self, srv: LiveServer, quiet: str, flood: str, period_s: float, t0: float):
        self.srv, self.quiet, self.flood, self.period_s, self.t0 = srv, quiet, flood, period_s, t0
        self.statuses: collections.Counter = collections.Counter()
        self.probe: dict[bool, list[float]] = {False: [], True: []}
        self.probe_status: collections.Counter = collections.Counter()
        self.details: list[str] = []  # the flood's answers other than 200 and 429
        self.lock = threading.Lock()

    def on(self) -> bool:
        return int((time.monotonic() - self.t0) / self.period_s) % 2 == 1

    def flood_thread(self, stop_at: float) -> None:
        import concurrent.futures as cf

        def send(c: httpx.Client) -> None:
            t = time.perf_counter()
            try:
                r = c.post("/v1/score", json={"route": HOUR})
                status, text = r.status_code, r.text[:200]
            except httpx.HTTPError as exc:
                status, text = type(exc).__name__, str(exc)[:200]
            with self.lock:
                self.statuses[status] += 1
                if status not in (200, 429):
                    self.details.append(f"{status} after {time.perf_counter() - t:.1f} s: {text}")

        with self.srv.client(timeout=120, headers={"X-API-Key": self.flood},
                             limits=httpx.Limits(max_connections=32)) as c, cf.ThreadPoolExecutor(32) as pool:
            while time.monotonic() < stop_at:
                if self.on():
                    pool.submit(send, c)
                time.sleep(1 / 3)

    def probe_thread(self, stop_at: float) -> None:
        with self.srv.client(timeout=120, headers={"X-API-Key": self.quiet}) as c:
            while time.monotonic() < stop_at:
                flooding = self.on()
                t = time.perf_counter()
                try:
                    r = c.post("/v1/score", json={"route": SHORT})
                    status = r.status_code
                except httpx.HTTPError as exc:
                    r, status = None, type(exc).__name__
                took = time.perf_counter() - t
                with self.lock:
                    self.probe_status[status] += 1
                    if status == 200 and flooding == self.on():  # a probe across a switch counts for neither
                        self.probe[flooding].append(took)
                if status == 429 and r is not None:
                    time.sleep(float(r.headers.get("retry-after", "1")))
                time.sleep(1.0)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration-s", type=float, default=600.0)
    parser.add_argument("--clients", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--flood", action="store_true", help="two keys, one of them flooding (see above)")
    parser.add_argument("--flood-period-s", type=float, default=60.0)
    args = parser.parse_args()
    session = Session()
    tum = route_text(600.0)
    with tempfile.TemporaryDirectory() as tmp:
        keys: dict[str, str] = {}
        settings = {}
        if args.flood:
            keys = write_keys(Path(tmp) / "keys.yaml", {
                "quiet": {"scopes": ["score", "plan"], "quota": {"rate_per_s": 1000, "burst": 1000, "jobs": 100}},
                "flood": {"scopes": ["score"], "quota": {"rate_per_s": 3, "burst": 3}}})
            settings = {"api_keys_file": Path(tmp) / "keys.yaml", "metrics": "public"}
        srv = LiveServer(Path(tmp), workers=1, score_workers=2, body_timeout_s=5, header_timeout_s=5,
                         request_timeout_s=60, **settings).start(timeout_s=300)
        try:
            soak = Soak(srv, tum, args.seed, keys.get("quiet"))
            with srv.client(timeout=120, headers=soak.headers) as c:  # warm every path once before the first reading
                for _ in range(2):
                    c.post("/v1/score", json={"route": {"format": "tum", "text": tum}})
                    c.post("/v1/score/plot", json={"route": FIGURE_EIGHT})
            time.sleep(2)
            server_pid = srv.proc.pid
            rss0 = tree_rss_mb(server_pid)
            srv0, pool0 = rss_mb([server_pid]), rss_mb(workers_of(server_pid))
            procs = Processes(server_pid)
            procs.sample()
            procs.thread.start()
            t0 = time.monotonic()
            stop_at = t0 + args.duration_s
            threads = [threading.Thread(target=soak.client, args=(stop_at, args.seed * 1000 + i))
                       for i in range(args.clients)]
            flood = None
            if args.flood:
                flood = Flood(srv, keys["quiet"], keys["flood"], args.flood_period_s, t0)
                threads.append(threading.Thread(target=flood.flood_thread, args=(stop_at,)))
                threads.append(threading.Thread(target=flood.probe_thread, args=(stop_at,)))
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            elapsed = time.monotonic() - t0
            time.sleep(5)  # let the last job workers exit and replaced scoring workers start
            procs.stop.set()
            procs.sample()
            rss1 = tree_rss_mb(server_pid)
            srv1, pool1 = rss_mb([server_pid]), rss_mb(workers_of(server_pid))
            orphans = procs.orphans()
        finally:
            srv.stop()
            server_log = srv.log.read_text(errors="replace")
        time.sleep(3)
        left = procs.alive()
        for pid in left:
            try:
                cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
                state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[:2]
            except OSError:
                cmd, state = "(gone)", []
            print(f"left behind: pid {pid} {state} {cmd[:200]}")
    total = sum(soak.counts.values())
    errors_5xx = sum(n for (k, s), n in soak.counts.items() if s >= 500)
    print(f"machine: {machine()}")
    print(f"soak: {args.clients} clients, {elapsed:.0f} s, {total} requests ({total / elapsed:.1f}/s), "
          f"{errors_5xx} answers 5xx or no answer, {len(soak.unexpected)} unexpected")
    for (kind, status), n in sorted(soak.counts.items()):
        lat = soak.latency.get(kind) or [0.0]
        print(f"  {kind:<40} {status}  {n:>6}   p50 {pct(lat, 50) * 1e3:7.0f} ms   p99 {pct(lat, 99) * 1e3:7.0f} ms")
    figures: dict = {"duration_s": round(elapsed), "clients": args.clients, "requests": total,
                     "answers_5xx_or_none": errors_5xx, "unexpected": len(soak.unexpected)}
    for kind in ("score 90 s", "score 10 min"):
        lat = soak.latency.get(kind) or [float("nan")]
        print(f"valid {kind}: p50 {pct(lat, 50) * 1e3:.0f} ms, p99 {pct(lat, 99) * 1e3:.0f} ms "
              f"over {len(lat)} requests")
        figures[f"valid {kind}"] = {"p50_ms": round(pct(lat, 50) * 1e3), "p99_ms": round(pct(lat, 99) * 1e3),
                                    "requests": len(soak.latency.get(kind, []))}
    shed = soak.shed_latency or [float("nan")]
    print(f"429 (overloaded, Retry-After): {len(soak.shed_latency)} answers, p50 {pct(shed, 50) * 1e3:.0f} ms, "
          f"max {max(shed) * 1e3:.0f} ms")
    figures["answers_429"] = len(soak.shed_latency)
    growth = (srv1 - srv0) / srv0
    pools = [pool0, pool1] + [b for _, _, b, _ in procs.memory]
    print(f"server process RSS: {srv0:.0f} MiB warm → {srv1:.0f} MiB at the end ({100 * growth:+.1f} %, "
          f"within 20 %: {abs(growth) <= 0.20})")
    print(f"not gated: scoring pool {pool0:.0f} → {pool1:.0f} MiB (from {min(pools):.0f} to {max(pools):.0f} "
          f"over the soak), whole tree {rss0:.0f} → {rss1:.0f} MiB ({100 * (rss1 - rss0) / rss0:+.1f} %)")
    figures.update({"server_rss_mib": [round(srv0), round(srv1)], "server_rss_growth_pct": round(100 * growth, 1),
                    "pool_rss_mib": [round(pool0), round(pool1)], "pool_rss_range_mib": [round(min(pools)), round(max(pools))],
                    "tree_rss_mib": [round(rss0), round(rss1)],
                    "tree_rss_growth_pct": round(100 * (rss1 - rss0) / rss0, 1)})
    print(f"processes: {len(procs.seen)} seen below the server, {len(orphans)} orphaned during the soak, "
          f"{len(left)} alive after its shutdown")
    if procs.memory:
        half = procs.memory[len(procs.memory) // 2]
        print("memory every 30 s [MiB] (s: server, pool, tree): " + ", ".join(
            f"{t:.0f}: {a:.0f}/{b:.0f}/{c:.0f}" for t, a, b, c in procs.memory))
        figures["memory_mib_every_30_s"] = [[round(t), round(a), round(b), round(c)] for t, a, b, c in procs.memory]
        figures["server_rss_growth_second_half_pct"] = round(100 * (srv1 - half[1]) / half[1], 1)
    figures.update({"processes_seen": len(procs.seen), "orphaned": len(orphans), "left_behind": len(left)})
    fair = True
    if flood is not None:
        calm, loud = flood.probe[False], flood.probe[True]
        ratio = (statistics.median(loud) / statistics.median(calm)) if calm and loud else float("nan")
        fair = (bool(calm and loud) and ratio <= 3 and set(flood.statuses) <= {200, 429}
                and set(flood.probe_status) <= {200, 429})
        print(f"flooding key: {dict(flood.statuses)} (200 or 429 only: {set(flood.statuses) <= {200, 429}})")
        for d in flood.details[:10]:
            print("   flood:", d)
        print(f"quiet key's probe (20 s route, 1/s): p50 {statistics.median(calm) * 1e3 if calm else float('nan'):.0f} ms "
              f"without the flood ({len(calm)}), {statistics.median(loud) * 1e3 if loud else float('nan'):.0f} ms "
              f"with it ({len(loud)}): ×{ratio:.2f} (within 3×: {ratio <= 3}); statuses {dict(flood.probe_status)}")
        figures["flood"] = {"statuses": {str(k): v for k, v in flood.statuses.items()},
                            "quiet_probe_without_ms": spread([x * 1e3 for x in calm], 1) if calm else None,
                            "quiet_probe_with_ms": spread([x * 1e3 for x in loud], 1) if loud else None,
                            "quiet_probe_ratio": round(ratio, 2),
                            "quiet_probe_statuses": {str(k): v for k, v in flood.probe_status.items()}}
    every = collections.Counter({s: n for (_, s), n in soak.counts.items()})
    if flood is not None:
        every.update(flood.statuses)
        every.update(flood.probe_status)
    n503 = every.get(503, 0)
    n5xx = sum(n for s, n in every.items() if not isinstance(s, int) or s >= 500)
    print(f"every key, every client: {n503} × 503, {n5xx} × 5xx or no answer")
    figures.update({"answers_503_all_keys": n503, "answers_5xx_or_none_all_keys": n5xx})
    if soak.unexpected:
        print("unexpected:", collections.Counter(soak.unexpected).most_common(10))
        for d in soak.details[:10]:
            print("  ", d)
    if soak.unexpected or (flood is not None and flood.details):
        for line in [x for x in server_log.splitlines() if "WARNING" in x or "ERROR" in x][:30]:
            print("   server:", line[:200])
    ok = errors_5xx == 0 and not soak.unexpected and abs(growth) <= 0.20 and not orphans and not left and fair
    figures["passed"] = ok
    path = session.record("soak_flood" if args.flood else "soak", figures,
                          note="mixed and hostile traffic on loopback" + (
                              "; two keys, one flooding hour-long routes every other period" if args.flood else ""))
    print("PASS" if ok else "FAIL", "→", path)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
