"""Latency and throughput of ``POST /v1/score`` over loopback HTTP, with authentication off and on.

Starts two ``excite serve`` processes on free 127.0.0.1 ports (settings from the environment,
scoring workers = cores by default): one open, one with an API keys file (each request sends
``X-API-Key``; the key is hashed and looked up, its scope checked and its rate counted). The
route is the reference figure-eight (``trajectories/figure_eight.tum``) as TUM text, or with
``--minutes`` a figure-eight drive of that length:

1. one client, requests alternating between the two servers (only one is busy at a time, so
   both see the same machine) → p50/p99 latency of each and their ratio;
2. ``--clients`` concurrent clients against the server with keys → throughput (requests/s)
   and p50/p99 under load.

Every response must be 200 with a report; the run fails otherwise. Traffic stays on loopback
and the loops are bounded.

    python benchmarks/bench_api.py [--sequential 40] [--concurrent-requests 48] [--clients 8] [--minutes M]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from results import Session  # noqa: E402
from servers import LiveServer  # noqa: E402


def route_text(duration_s: float = 600.0) -> str:
    from excite.motion.maneuvers import figure_eight
    from excite.rig.config import load_rig
    from excite.io.routes import write_tum
    from excite.motion.vehicle import drive

    rig = load_rig("robotaxi")
    traj = drive(figure_eight(duration_s=duration_s), rig.suspension)
    with tempfile.TemporaryDirectory() as tmp:
        path = write_tum(traj, Path(tmp) / "figure_eight_10min.tum", rate_hz=10.0)
        return path.read_text()


def pct(xs: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(xs), q))


def machine() -> str:
    cpu = "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return f"{cpu}, {cores} cores, Python {platform.python_version()}, {platform.system()} {platform.release()}"


def load_avg() -> str:
    try:
        return Path("/proc/loadavg").read_text().split()[0]
    except OSError:
        return "?"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sequential", type=int, default=40, help="requests to each server, alternating")
    ap.add_argument("--concurrent-requests", type=int, default=48)
    ap.add_argument("--clients", type=int, default=8)
    ap.add_argument("--minutes", type=float, default=None,
                    help="a figure-eight drive of this length instead of the reference file")
    ap.add_argument("--score-workers", type=int,
                    default=len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else 2)
    args = ap.parse_args()
    session = Session()

    if args.minutes:
        text, name = route_text(60.0 * args.minutes), f"figure_eight_{args.minutes:g}min"
    else:
        text, name = (Path(__file__).resolve().parents[1] / "trajectories" / "figure_eight.tum").read_text(), "figure_eight"
    body = {"route": {"name": name, "format": "tum", "text": text}, "rig": "robotaxi"}
    errors: list[str] = []
    loads0 = load_avg()

    from servers import write_keys

    with tempfile.TemporaryDirectory() as tmp:
        secrets = write_keys(Path(tmp) / "keys.yaml", {"bench": {"scopes": ["score"], "quota": {
            "rate_per_s": 10_000, "burst": 10_000}}})
        (Path(tmp) / "open").mkdir()
        (Path(tmp) / "keyed").mkdir()
        open_srv = LiveServer(Path(tmp) / "open", workers=0, score_workers=args.score_workers,
                              request_timeout_s=300).start()
        keyed_srv = LiveServer(Path(tmp) / "keyed", workers=0, score_workers=args.score_workers,
                               request_timeout_s=300, api_keys_file=Path(tmp) / "keys.yaml").start()
        try:
            def call(client: httpx.Client) -> float:
                t0 = time.perf_counter()
                r = client.post("/v1/score", json=body)
                dt = time.perf_counter() - t0
                if r.status_code != 200 or "score" not in r.json():
                    errors.append(f"{r.status_code}: {r.text[:200]}")
                return dt

            key = {"X-API-Key": secrets["bench"]}
            with open_srv.client(timeout=300) as o, keyed_srv.client(timeout=300, headers=key) as k:
                for _ in range(3):  # warm-up: both servers' workers have loaded everything
                    call(o), call(k)
                seq_open, seq_keyed = [], []
                for i in range(args.sequential):  # alternating, starting with each in turn
                    first, second = ((o, seq_open), (k, seq_keyed)) if i % 2 == 0 else ((k, seq_keyed), (o, seq_open))
                    first[1].append(call(first[0]))
                    second[1].append(call(second[0]))
            open_srv.stop()
            clients = [keyed_srv.client(timeout=300, headers=key) for _ in range(args.clients)]
            per = -(-args.concurrent_requests // args.clients)
            t0 = time.perf_counter()
            with ThreadPoolExecutor(args.clients) as ex:
                loads = list(ex.map(lambda c: [call(c) for _ in range(per)], clients))
            wall = time.perf_counter() - t0
            for c in clients:
                c.close()
        finally:
            open_srv.stop()
            keyed_srv.stop()

    conc = [x for xs in loads for x in xs]
    p50o, p50k = pct(seq_open, 50), pct(seq_keyed, 50)
    print(f"machine: {machine()}; load average {loads0} at the start, {load_avg()} at the end")
    print(f"route: {name}, TUM text {len(text) / 1024:.0f} KiB, {text.count(chr(10))} lines; "
          f"rig robotaxi; score workers {args.score_workers}")
    for what, seq in (("authentication off", seq_open), ("authentication on ", seq_keyed)):
        print(f"one client, {what} ({len(seq)} requests): p50 {1e3 * pct(seq, 50):.1f} ms, "
              f"p99 {1e3 * pct(seq, 99):.1f} ms, mean {1e3 * statistics.mean(seq):.1f} ms")
    print(f"on / off: p50 ×{p50k / p50o:.3f}, p99 ×{pct(seq_keyed, 99) / pct(seq_open, 99):.3f}")
    print(f"{args.clients} concurrent clients, authentication on ({len(conc)} requests in {wall:.1f} s): "
          f"throughput {len(conc) / wall:.2f} req/s, p50 {1e3 * pct(conc, 50):.0f} ms, "
          f"p99 {1e3 * pct(conc, 99):.0f} ms")
    print(f"errors: {len(errors)}")
    for e in errors[:5]:
        print("  ", e)
    if errors:
        return 1
    ms = lambda xs, q: round(1e3 * pct(xs, q), 1)  # noqa: E731
    session.record("api", {
        "one_client_auth_off_p50_p99_ms": [ms(seq_open, 50), ms(seq_open, 99)],
        "one_client_auth_on_p50_p99_ms": [ms(seq_keyed, 50), ms(seq_keyed, 99)],
        "auth_on_over_off_p50": round(p50k / p50o, 3),
        f"{args.clients}_clients_throughput_req_per_s": round(len(conc) / wall, 2),
        f"{args.clients}_clients_p50_p99_ms": [ms(conc, 50), ms(conc, 99)],
    }, note=f"POST /v1/score over loopback, route {name} ({len(text) / 1024:.0f} KiB TUM text), rig robotaxi, "
            f"{args.score_workers} scoring workers; one client alternating between a server without and one with "
            f"API keys ({args.sequential} requests each), then {args.clients} concurrent clients on the one with keys "
            f"({len(conc)} requests)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
