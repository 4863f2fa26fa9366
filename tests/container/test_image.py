"""The container image: a fresh container (given an API keys file) is healthy within 10 s of its
start and scores the figure-eight with a key; its native module was built at install and the
optimizer's model for the default problem compiled at build, nothing was run at build to fill a
cache, and nothing is compiled or cached at start; one copy of the code, no matplotlib warning;
without keys the image refuses to serve its 0.0.0.0 with a one-line reason.

Runs when ``EXCITE_IMAGE`` names a built image (``.ci/run`` builds it with podman and sets it);
skipped otherwise. Needs podman on the PATH (and, in this sandbox, ``CONTAINERS_CONF`` pointing
at container/containers.conf).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import time
import urllib.error
import urllib.request
import uuid

import pytest
from helpers import REPO

IMAGE = os.environ.get("EXCITE_IMAGE")
PODMAN = shutil.which("podman")
ROUTE = REPO / "trajectories" / "figure_eight_control.csv"
HEALTHY_WITHIN_S = 10.0

pytestmark = [pytest.mark.container, pytest.mark.slow,
              pytest.mark.skipif(not (IMAGE and PODMAN), reason="EXCITE_IMAGE unset or no podman")]


def podman(*args: str, check: bool = True, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([PODMAN, *args], capture_output=True, text=True, check=check, timeout=timeout)


KEY = "exk_container-test-" + uuid.uuid4().hex


@pytest.fixture
def container(tmp_path):
    """A fresh container of the image with one admin key, its port published on loopback;
    removed afterwards."""
    keys = tmp_path / "keys.yaml"
    keys.write_text("keys:\n  - {id: ci, owner: ci, scopes: [admin], sha256: '%s'}\n"
                    % hashlib.sha256(KEY.encode()).hexdigest())
    keys.chmod(0o644)
    name = f"excite-test-{uuid.uuid4().hex[:10]}"
    started = time.monotonic()
    podman("run", "-d", "--name", name, "-p", "127.0.0.1::8000", "-v", f"{keys}:/etc/excite/keys.yaml:ro",
           "-e", "EXCITE_API_KEYS_FILE=/etc/excite/keys.yaml", IMAGE)
    try:
        host_port = podman("port", name, "8000").stdout.split()[0]  # 127.0.0.1:PORT
        yield name, f"http://{host_port}", started
    finally:
        out = podman("logs", name, check=False)
        logs = out.stdout + out.stderr
        podman("rm", "-f", "-v", "-t", "5", name, check=False)  # -v: its anonymous /data volume
        print(logs[-4000:])  # shown by pytest when the test failed


def test_fresh_container_healthy_within_10s_and_scores(container):
    name, url, started = container
    # poll /healthz from the host (cheap: no process in the container per probe)
    while True:
        try:
            with urllib.request.urlopen(f"{url}/healthz", timeout=2) as r:
                if r.status == 200:
                    break
        except (urllib.error.URLError, ConnectionError, TimeoutError):
            pass
        elapsed = time.monotonic() - started
        assert elapsed < HEALTHY_WITHIN_S, f"/healthz not 200 within {HEALTHY_WITHIN_S:g} s"
        time.sleep(0.25)
    healthy_s = time.monotonic() - started
    # the image's own HEALTHCHECK agrees (run by hand: without systemd podman runs no timer)
    assert podman("healthcheck", "run", name, check=False).returncode == 0
    assert podman("inspect", "--format", "{{.State.Health.Status}}", name).stdout.strip() == "healthy"
    assert time.monotonic() - started < HEALTHY_WITHIN_S
    print(f"healthy {healthy_s:.1f} s after podman run")

    body = {"route": {"name": "figure_eight", "format": "control_csv", "text": ROUTE.read_text()},
            "rig": "robotaxi"}
    req = urllib.request.Request(f"{url}/v1/score", json.dumps(body).encode(),
                                 {"content-type": "application/json", "x-api-key": KEY})
    with urllib.request.urlopen(req, timeout=120) as r:
        assert r.status == 200
        report = json.load(r)
    # the figure-eight's floor in trajectories/manifest.yaml (today 1.9e-4), as `excite batch` gates it
    assert report["score"] >= 1.0e-4, report["score"]
    assert report["rank"] > 0 and report["parameters"]

    # nothing compiled at start or by the first score, nothing written to the cache
    changed = podman("diff", name).stdout.split("\n")
    assert not [c for c in changed if "/var/cache/excite" in c], changed
    logs = podman("logs", name).stdout + podman("logs", name).stderr
    assert "Matplotlib" not in logs and "not writable" not in logs
    # one copy of the code, the installed package (server and workers import the same files)
    where = podman("exec", name, "python", "-c",
                   "import excite, api; print(excite.__file__, api.__file__)").stdout.split()
    assert all(p.startswith("/opt/excite/lib/python3.11/site-packages/") for p in where), where
    copies = podman("exec", name, "find", "/", "-xdev", "-path", "*/excite/score/evaluate.py",
                    check=False).stdout.split()
    assert copies == ["/opt/excite/lib/python3.11/site-packages/excite/score/evaluate.py"], copies
    # the optimizer's model for the default problem compiled at build: a job of that shape
    # (EXCITE_COMPILE=0, as the service's jobs run) starts compiled; its reference maneuvers were
    # not scored at build (no evaluator ran there to fill a cache)
    probe = ("from excite.plan import OptimizeSettings; from excite.plan.problem import Problem; "
             "from excite.plan.transcription import cached; from excite.plan import candidates as c; "
             "from excite.rig.config import load_rig; r = load_rig('robotaxi'); s = OptimizeSettings().for_rig(r); "
             "print(cached(Problem.of(r, s)).info.mode, '|', c.cached_references(r, s, s.lot) is not None)")
    out = podman("exec", "-e", "EXCITE_COMPILE=0", name, "python", "-c", probe, check=False)
    assert out.stdout.strip() == "compiled | False", out.stdout + out.stderr
    # the key is needed: without one, 401
    req = urllib.request.Request(f"{url}/v1/score", json.dumps(body).encode(), {"content-type": "application/json"})
    with pytest.raises(urllib.error.HTTPError) as denied:
        urllib.request.urlopen(req, timeout=60)
    assert denied.value.code == 401


def test_without_keys_the_image_refuses_to_serve_its_network():
    out = podman("run", "--rm", IMAGE, check=False, timeout=120)
    lines = [line for line in (out.stdout + out.stderr).splitlines() if line.strip()]
    assert out.returncode == 1, out
    assert lines[-1].startswith("excite: error: refusing to serve 0.0.0.0 without API keys"), lines
