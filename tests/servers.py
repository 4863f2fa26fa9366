"""Helpers for the API tests (no tests here): a live uvicorn server on a loopback port, and
job functions injected through ``create_app(job_function=...)``."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable

import httpx

TESTS_DIR = Path(__file__).resolve().parent
REPO = TESTS_DIR.parent


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


SERVE_WITH_JOB = """
from api import Settings, create_app, serving
from api.command import log_service
log_service("info")
serving.run(create_app(job_function={job_function!r}), Settings().header_timeout_s, "127.0.0.1", {port},
            "warning")
"""


class LiveServer:
    """``excite serve`` in a subprocess on 127.0.0.1, settings from the environment."""

    def __init__(self, tmp: Path, **settings: Any):
        self.tmp = tmp
        self.settings = {"db_path": str(tmp / "jobs.sqlite3"), "score_workers": 1, **settings}
        self.port = free_port()
        self.proc: subprocess.Popen | None = None
        self.log = tmp / f"server-{self.port}.log"

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def start(self, timeout_s: float = 90.0) -> "LiveServer":
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([str(TESTS_DIR), str(REPO), env.get("PYTHONPATH", "")])
        settings = dict(self.settings)
        job_function = settings.pop("job_function", None)
        env.update({f"EXCITE_{k.upper()}": str(v) for k, v in settings.items()})
        if job_function is None:
            cmd = [sys.executable, "-c", "import sys; from excite.cli.app import main; sys.exit(main(sys.argv[1:]))",
                   "serve", "--host", "127.0.0.1", "--port", str(self.port), "--log-level", "info"]
        else:  # a stand-in job: built here, it is no setting of the service
            cmd = [sys.executable, "-c", SERVE_WITH_JOB.format(job_function=job_function, port=self.port)]
        with open(self.log, "ab") as log:
            self.proc = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT, cwd=self.tmp)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited with {self.proc.returncode}:\n{self.log.read_text()}")
            try:
                if httpx.get(self.url + "/readyz", timeout=2).status_code == 200:
                    return self
            except httpx.HTTPError:
                pass
            time.sleep(0.2)
        self.stop()
        raise RuntimeError(f"server not ready in {timeout_s} s:\n{self.log.read_text()}")

    def kill9(self) -> None:
        assert self.proc is not None
        os.kill(self.proc.pid, signal.SIGKILL)
        self.proc.wait(10)

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()

    def client(self, **kw: Any) -> httpx.Client:
        return httpx.Client(base_url=self.url, timeout=kw.pop("timeout", 120), **kw)


def wait_job(client: httpx.Client, location: str, done: Callable[[dict], bool] | None = None,
             timeout_s: float = 120.0) -> dict[str, Any]:
    """Poll a job until ``done(job)`` (default: a final status)."""
    done = done or (lambda j: j["status"] in ("succeeded", "failed", "cancelled"))
    deadline = time.monotonic() + timeout_s
    while True:
        r = client.get(location)
        assert r.status_code == 200, r.text
        job = r.json()
        if done(job):
            return job
        if time.monotonic() > deadline:
            raise AssertionError(f"job not done in {timeout_s} s: {job}")
        time.sleep(0.2)


def processes_with(text: str) -> list[int]:
    """Pids whose command line contains ``text`` (a job id: its worker)."""
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                if text.encode() in (d / "cmdline").read_bytes():
                    out.append(int(d.name))
            except OSError:
                pass
    return out


def slow_job(request: dict[str, Any], progress: Callable[[dict], None],
             should_stop: Callable[[], bool]) -> dict[str, Any]:
    """A stand-in optimizer: ``time_budget_s`` of 0.1 s iterations, then a real report of the
    reference figure eight (so downloads work)."""
    from api.scoring import plain
    from excite.score.evaluate import evaluate
    from excite.motion.maneuvers import figure_eight
    from excite.rig.config import load_rig
    from excite.motion.vehicle import drive

    n = int(request["time_budget_s"] / 0.1)
    cancelled = False
    for i in range(n):
        if should_stop():
            cancelled = True
            break
        progress({"iteration": i, "score": 1e-3 * i, "constraint_violation": 0.0,
                  "elapsed_s": 0.1 * i, "phase": "optimize"})
        time.sleep(0.1)
    rig = load_rig("robotaxi")
    prof = figure_eight(duration_s=request["duration_s"])
    rep = evaluate(drive(prof, rig.suspension), rig)
    return {"report": plain(rep.to_dict()), "comparison": [{"name": "figure_eight", "score": rep.score}],
            "status": "cancelled" if cancelled else "optimal", "iterations": i, "elapsed_s": 0.1 * i,
            "cancelled": cancelled, "score": rep.score, "model_score": None, "timings_s": {},
            "message": "stand-in", "profile": plain(prof)}


def write_keys(path: Path, keys: dict[str, dict[str, Any]]) -> dict[str, str]:
    """A keys file at ``path`` with one key per ``id → {"scopes": [...], "owner"?, "quota"?}``;
    returns ``id → secret``."""
    import yaml

    from api.auth import hash_key, new_key

    secrets, entries = {}, []
    for key_id, spec in keys.items():
        secrets[key_id] = new_key()
        entry = {"id": key_id, "owner": spec.get("owner", key_id), "scopes": spec["scopes"],
                 "sha256": hash_key(secrets[key_id])}
        if "quota" in spec:
            entry["quota"] = spec["quota"]
        entries.append(entry)
    path.write_text(yaml.safe_dump({"keys": entries}))
    return secrets


def quick_job(request: dict[str, Any], progress: Callable[[dict], None],
              should_stop: Callable[[], bool]) -> dict[str, Any]:
    """A stand-in job of ``time_budget_s`` seconds that records its end in the file named by
    ``EXCITE_TEST_JOB_LOG`` (one line: job name and pid) and returns a minimal result."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < request["time_budget_s"]:
        if should_stop():
            break
        progress({"iteration": 0, "elapsed_s": time.monotonic() - t0, "phase": "optimize"})
        time.sleep(0.05)
    log = os.environ.get("EXCITE_TEST_JOB_LOG")
    if log:
        with open(log, "a") as fh:
            fh.write(f"{request['name']} {os.getpid()} {time.time():.6f}\n")
    return json.loads(Path(os.environ["EXCITE_TEST_JOB_RESULT"]).read_text())


def job_result_file(path: Path) -> Path:
    """A valid job result (the figure eight's report) for :func:`quick_job` to return."""
    from api.scoring import plain
    from excite.motion.maneuvers import figure_eight
    from excite.motion.vehicle import drive
    from excite.rig.config import load_rig
    from excite.score.evaluate import evaluate

    rig = load_rig("robotaxi")
    prof = figure_eight(duration_s=20.0)
    rep = evaluate(drive(prof, rig.suspension), rig)
    path.write_text(json.dumps({
        "report": plain(rep.to_dict()), "comparison": [], "status": "stand-in", "iterations": 0,
        "elapsed_s": 0.0, "cancelled": False, "score": rep.score, "model_score": None, "timings_s": {},
        "message": "stand-in", "profile": plain(prof)}))
    return path


def tree_job(request: dict[str, Any], progress: Callable[[dict], None],
             should_stop: Callable[[], bool]) -> dict[str, Any]:
    """A stand-in job that starts a child process (as the optimizer's pool does), a grandchild
    in a session of its own, and then ignores cancellation: only killing ends it."""
    marker = f"excite-tree-job-{request['name']}"
    subprocess.Popen([sys.executable, "-c", "import time; time.sleep(600)", marker])
    subprocess.Popen([sys.executable, "-c", "import time; time.sleep(600)", marker], start_new_session=True)
    while True:
        progress({"iteration": 0, "phase": "optimize"})
        time.sleep(0.1)
