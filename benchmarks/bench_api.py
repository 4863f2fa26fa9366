"""Latency and throughput of ``POST /v1/score`` for a 10-minute route, over loopback HTTP.

Starts ``excite serve`` on a free 127.0.0.1 port (settings from the environment, scoring
workers = cores by default), sends a 10-minute figure-eight drive as TUM text:

1. sequential requests → p50/p99 latency;
2. 8 concurrent clients → throughput (requests/s) and p50/p99 under load.

Every response must be 200 with a report; the run fails otherwise. Traffic stays on loopback
and the loops are bounded.

    python benchmarks/bench_api.py [--sequential 30] [--concurrent-requests 48] [--clients 8]
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
from test_api_support import LiveServer  # noqa: E402


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


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sequential", type=int, default=30)
    ap.add_argument("--concurrent-requests", type=int, default=48)
    ap.add_argument("--clients", type=int, default=8)
    ap.add_argument("--score-workers", type=int,
                    default=len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else 2)
    args = ap.parse_args()

    text = route_text()
    body = {"route": {"name": "figure_eight_10min", "format": "tum", "text": text}, "rig": "robotaxi"}
    errors: list[str] = []

    with tempfile.TemporaryDirectory() as tmp:
        srv = LiveServer(Path(tmp), workers=0, score_workers=args.score_workers,
                         request_timeout_s=300).start()
        try:
            def call(client: httpx.Client) -> float:
                t0 = time.perf_counter()
                r = client.post("/v1/score", json=body)
                dt = time.perf_counter() - t0
                if r.status_code != 200 or "score" not in r.json():
                    errors.append(f"{r.status_code}: {r.text[:200]}")
                return dt

            with srv.client(timeout=300) as c:
                call(c)  # warm-up
                seq = [call(c) for _ in range(args.sequential)]
            clients = [srv.client(timeout=300) for _ in range(args.clients)]
            per = -(-args.concurrent_requests // args.clients)
            t0 = time.perf_counter()
            with ThreadPoolExecutor(args.clients) as ex:
                loads = list(ex.map(lambda c: [call(c) for _ in range(per)], clients))
            wall = time.perf_counter() - t0
            for c in clients:
                c.close()
        finally:
            srv.stop()

    conc = [x for xs in loads for x in xs]
    print(f"machine: {machine()}")
    print(f"route: 10-minute figure eight, TUM text {len(text) / 1024:.0f} KiB, {text.count(chr(10))} lines; "
          f"rig robotaxi; score workers {args.score_workers}")
    print(f"sequential ({len(seq)} requests): p50 {1e3 * pct(seq, 50):.0f} ms, p99 {1e3 * pct(seq, 99):.0f} ms, "
          f"mean {1e3 * statistics.mean(seq):.0f} ms")
    print(f"{args.clients} concurrent clients ({len(conc)} requests in {wall:.1f} s): "
          f"throughput {len(conc) / wall:.2f} req/s, p50 {1e3 * pct(conc, 50):.0f} ms, "
          f"p99 {1e3 * pct(conc, 99):.0f} ms")
    print(f"errors: {len(errors)}")
    for e in errors[:5]:
        print("  ", e)
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
