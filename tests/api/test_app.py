"""In-process checks of the service's pieces: public names, settings, the job store's
durability rules, the time limit and the catch-all handler."""

from __future__ import annotations

import sqlite3

import pytest
from pydantic import ValidationError

import api
from api import Settings, create_app
from api.store import JobStore as SqliteStore


def test_public_names():
    assert sorted(api.__all__) == ["Settings", "create_app"]


def test_settings_from_environment_are_validated(monkeypatch, tmp_path):
    monkeypatch.setenv("EXCITE_DB_PATH", str(tmp_path / "j.sqlite3"))
    monkeypatch.setenv("EXCITE_MAX_SAMPLES", "1234")
    s = Settings()
    assert s.max_samples == 1234 and s.db_path == tmp_path / "j.sqlite3"
    monkeypatch.setenv("EXCITE_REQUEST_TIMEOUT_S", "nan")
    with pytest.raises(ValidationError):
        Settings()
    monkeypatch.delenv("EXCITE_REQUEST_TIMEOUT_S")
    monkeypatch.setenv("EXCITE_DB_PATH", str(tmp_path / "missing" / "j.sqlite3"))
    with pytest.raises(ValidationError, match="does not exist"):
        Settings()


def test_store_re_queues_jobs_of_a_dead_server_and_ignores_stale_workers(tmp_path):
    store = SqliteStore(tmp_path / "j.sqlite3")
    a = store.create("maneuver", {"x": 1})
    b = store.create("maneuver", {"x": 2})
    assert store.claim("host/boot/1/dead", 30) == (a, 1)
    store.progress(a, 1, {"iteration": 3})
    # its replica is alive (a live lease, another host): nobody takes the job over
    assert store.reclaim("me") == [] and store.get(a)["status"] == "running"
    # the replica dies: its lease expires and the next replica re-queues a (b was never started)
    with sqlite3.connect(tmp_path / "j.sqlite3") as db:  # the test ages the lease
        db.execute("UPDATE jobs SET lease_expires = 0 WHERE id = ?", (a,))
    assert store.reclaim("me") == [a]
    assert store.get(a)["status"] == "queued" and store.get(a)["progress"] == {"iteration": 3}
    assert store.claim("me", 30) == (a, 2)
    # the first run's straggler can neither write nor finish
    assert store.request_of(a, 1) is None and store.request_of(a, 2) == {"x": 1}
    assert not store.finish(a, 1, "succeeded", result={"stale": True})
    assert store.finish(a, 2, "succeeded", result={"ok": True})
    assert store.get(a)["result"] == {"ok": True}
    assert store.cancel(b) == "cancelled" and store.claim("me", 30) is None
    assert store.counts() == {"succeeded": 1, "cancelled": 1}


def test_time_limit_and_no_traceback(tmp_path):
    from fastapi.testclient import TestClient

    app = create_app(Settings(db_path=tmp_path / "j.sqlite3", workers=0, score_workers=1,
                              request_timeout_s=0.05))
    with TestClient(app, base_url="http://localhost", raise_server_exceptions=False) as c:
        r = c.post("/v1/score", json={"route": {"waypoints": [[0, 0], [300, 0], [300, 200], [0, 200]]}})
        assert r.status_code == 503 and "0.05 s" in r.json()["detail"], r.text
        assert r.headers["content-type"].startswith("application/problem+json")

    app = create_app(Settings(db_path=tmp_path / "j.sqlite3", workers=0, score_workers=1))

    @app.get("/boom")
    def boom():
        raise RuntimeError("secret internals")

    with TestClient(app, base_url="http://localhost", raise_server_exceptions=False) as c:
        r = c.get("/boom")
        assert r.status_code == 500 and "secret" not in r.text and "Traceback" not in r.text
        assert r.json()["title"] == "Internal server error"


def test_response_schemas_declare_exactly_the_library_json():
    """The OpenAPI response models and the library's JSON (Report.to_dict, OptimizeResult.to_dict)
    name the same fields, down to the nested rows: neither can drift from the other."""
    import numpy as np

    from api import schemas
    from excite.score.evaluate import Options, evaluate
    from excite.plan.settings import OptimizeResult
    from excite.rig.config import load_rig
    from excite.motion.vehicle import ControlProfile, drive

    rig = load_rig("robotaxi")
    t = np.linspace(0, 20, 21)
    rep = evaluate(drive(ControlProfile(t, 5 + 2 * np.sin(t), 0.1 * np.sin(t / 2)), rig.suspension), rig,
                   Options(segments=2))
    d = rep.to_dict()
    fields = lambda model: set(model.model_fields)  # noqa: E731
    assert fields(schemas.Report) == set(d)
    for model, rows in [(schemas.Column, d["column_map"]), (schemas.ParameterOut, d["parameters"]),
                        (schemas.WeakModeOut, d["weak_modes"]), (schemas.SegmentOut, d["segments"])]:
        assert rows and all(fields(model) == set(r) for r in rows), model.__name__
    result = OptimizeResult(profile=None, trajectory=None, report=rep, comparison=[], status="optimal",
                            iterations=0, elapsed_s=0.0, cancelled=False)
    assert fields(schemas.JobResult) == set(result.to_dict())
    # a drivable plan's result has the same fields
    from excite.motion.vehicle import Limits
    from excite.plan.drivable.plan import DrivablePlan, Element, build
    from excite.plan.drivable.robust import Robust
    from excite.plan.drivable.search import DrivableResult

    built = build(DrivablePlan((Element("circles", dict(radius_m=8, speed_mps=6, laps=1), (0.0, 0.0, 0.0)),), 30.0),
                  Limits())
    dres = DrivableResult(built.plan, built, None, None, rep, Robust(1.0, np.ones(5)),
                          [{"plan": "circles×1", "score": 1.0, "score_quantile": 1.0, "quantile": 0.1, "chosen": True}],
                          1.0, {})
    assert fields(schemas.JobResult) == set(dres.to_dict())
