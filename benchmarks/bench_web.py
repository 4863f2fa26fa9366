"""Weight and first render of the planners' page (GET /), over loopback in headless Chromium.

Starts ``excite serve`` on a free 127.0.0.1 port and loads ``/`` ``--loads`` times, each in a
fresh browser context (empty cache). Per load: the bytes of every response the page fetched
(the page, its script and style sheet, ``/v1/rigs``), the browser's first contentful paint, and
the time until the page is usable (the rig list filled in). Needs Debian's ``chromium`` and the
``playwright`` package, like tests/api/test_page.py.

    python benchmarks/bench_web.py [--loads 20]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_api import machine  # noqa: E402
from results import Session, spread  # noqa: E402
from servers import LiveServer  # noqa: E402
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "api"))
from test_page import CHROMIUM_ARGS, _chromium  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--loads", type=int, default=20)
    args = ap.parse_args()
    session = Session()
    from playwright.sync_api import sync_playwright

    weights: list[dict[str, int]] = []
    fcp_ms: list[float] = []
    usable_ms: list[float] = []
    with tempfile.TemporaryDirectory() as tmp:
        srv = LiveServer(Path(tmp), workers=0, score_workers=1).start()
        try:
            with sync_playwright() as p:
                browser = p.chromium.launch(executable_path=_chromium(), args=CHROMIUM_ARGS)
                for _ in range(args.loads):
                    ctx = browser.new_context()
                    page = ctx.new_page()
                    sizes: dict[str, int] = {}
                    page.on("requestfinished", lambda r, sizes=sizes: sizes.__setitem__(
                        r.url.removeprefix(srv.url), r.sizes()["responseBodySize"]))
                    page.goto(srv.url + "/")
                    page.wait_for_selector("#rig-select option[value=robotaxi]", state="attached")
                    t = page.evaluate("""() => ({
                        fcp: performance.getEntriesByName('first-contentful-paint')[0]?.startTime,
                        usable: performance.now() })""")
                    fcp_ms.append(t["fcp"])
                    usable_ms.append(t["usable"])
                    weights.append(sizes)
                    ctx.close()
                browser.close()
        finally:
            srv.stop()

    last = weights[-1]
    print(f"machine: {machine()}")
    print(f"{args.loads} loads of / on loopback, fresh context each")
    for url, n in sorted(last.items()):
        print(f"  {url:24s} {n:7d} B")
    total = sum(last.values())
    static = sum(n for u, n in last.items() if not u.startswith("/v1/"))
    print(f"page weight: {total} B ({total / 1024:.1f} KiB) of which the page's own files {static} B")
    for name, xs in (("first contentful paint", fcp_ms), ("usable (rig list filled)", usable_ms)):
        print(f"{name}: median {statistics.median(xs):.0f} ms, range {min(xs):.0f}–{max(xs):.0f} ms")
    session.record("web", {"page_weight_bytes": total, "own_files_bytes": static, "responses_bytes": dict(sorted(last.items())),
                           "first_contentful_paint_ms": spread(fcp_ms, 0), "usable_ms": spread(usable_ms, 0)},
                   note="GET / on loopback in headless Chromium, a fresh browser context (empty cache) per load; "
                        "usable = the rig list filled in")
    return 0


if __name__ == "__main__":
    sys.exit(main())
