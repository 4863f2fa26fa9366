"""Screenshots of the documentation site for the site itself: its home page and one guide.

    python3 -m mkdocs build --site-dir /tmp/site && python3 docs/screenshots.py /tmp/site

Serves the built site on a free loopback port and photographs it with Debian's Chromium through
Playwright (``executable_path=/usr/bin/chromium``; ``playwright install`` is never needed), at
laptop width, into docs/site-home.png and docs/site-guide.png (a 256-colour palette keeps them
small).
"""

from __future__ import annotations

import functools
import http.server
import sys
import threading
from pathlib import Path

from PIL import Image
from playwright.sync_api import sync_playwright

DOCS = Path(__file__).resolve().parent
SHOTS = {"site-home.png": "", "site-guide.png": "guides/score/"}


def main(site: Path) -> None:
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(site))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path="/usr/bin/chromium")
            page = browser.new_page(viewport={"width": 1366, "height": 900})
            for name, path in SHOTS.items():
                page.goto(f"http://127.0.0.1:{server.server_address[1]}/{path}")
                page.wait_for_load_state("networkidle")
                out = DOCS / name
                page.screenshot(path=str(out))
                Image.open(out).convert("RGB").quantize(256).save(out, optimize=True)
                print(f"wrote {out} ({out.stat().st_size // 1024} KiB)")
            browser.close()
    finally:
        server.shutdown()


if __name__ == "__main__":
    main(Path(sys.argv[1]))
