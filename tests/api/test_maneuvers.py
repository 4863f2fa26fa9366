"""Lots that cannot be planned in (impossible or malformed) are refused when the job is submitted,
not after it has run."""

from __future__ import annotations

import time
import numpy as np
import pytest
from fastapi.testclient import TestClient
from api import Settings, create_app


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("surfaces")
    app = create_app(Settings(db_path=tmp / "jobs.sqlite3", workers=0, score_workers=1, max_lot_vertices=500,
                              max_route_duration_s=60, max_live_pose_rate_hz=400))
    with TestClient(app, base_url="http://localhost", raise_server_exceptions=False) as c:
        yield c


def _lot(ring, holes=(), local=True, **props) -> dict:
    feature = {"type": "Feature", "properties": props,
               "geometry": {"type": "Polygon", "coordinates": [ring, *holes]}}
    return {"type": "FeatureCollection", "properties": {"crs": "local"} if local else {}, "features": [feature]}


def _square(x0, y0, side, n=4):
    if n == 4:
        return [[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side], [x0, y0]]
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ring = [[x0 + side * np.cos(a), y0 + side * np.sin(a)] for a in t]
    return ring + [ring[0]]


def test_impossible_or_malformed_lots_are_refused_at_submission(client):
    ok = _lot(_square(0, 0, 60))
    assert client.post("/v1/maneuvers", json={"lot": ok, "time_budget_s": 1, "duration_s": 30}).status_code == 202
    feature = ok["features"][0]
    cases = {
        "properties a list": {**ok, "features": [{**feature, "properties": [1, 2]}]},
        "properties a string": {**ok, "features": [{**feature, "properties": "lot"}]},
        "geometry a list": {**ok, "features": [{**feature, "geometry": [[0, 0]]}]},
        "a one-number coordinate": _lot([[0, 0], [60], [60, 60], [0, 60], [0, 0]]),
        "a huge integer": _lot([[0, 0], [10**400, 0], [60, 60], [0, 60], [0, 0]]),
        "near the pole": _lot([[10, 89.9], [10.01, 89.9], [10.01, 89.91], [10, 89.91], [10, 89.9]], local=False),
        "a hemisphere": _lot([[-90, 0], [90, 0], [90, 80], [-90, 80], [-90, 0]], local=False),
        "self-intersecting": _lot([[0, 0], [60, 60], [60, 0], [0, 60], [0, 0]]),
        "zero area": _lot([[0, 0], [30, 0], [60, 0], [30, 0], [0, 0]]),
        "sides of 1e7 m": _lot(_square(0, 0, 1e7)),
        "a repeated vertex": _lot([[0, 0], [60, 0], [60, 0], [60, 60], [0, 60], [0, 0]]),
        "a hole across the outline": _lot(_square(0, 0, 60), [_square(50, 10, 20)]),
        "a hole outside": _lot(_square(0, 0, 60), [_square(100, 100, 5)]),
        "too many vertices": _lot(_square(0, 0, 60, n=600)),
        "a 10k x 10k keep-out test": _lot(_square(0, 0, 600, n=10_000), [_square(0, 0, 100, n=10_000)]),
    }
    for what, lot in cases.items():
        t0 = time.monotonic()
        r = client.post("/v1/maneuvers", json={"lot": lot, "time_budget_s": 1, "duration_s": 30})
        assert r.status_code == 422, (what, r.status_code, r.text[:300])
        body = r.json()
        assert body["errors"][0]["field"] == "lot", (what, body)
        assert time.monotonic() - t0 < 30, what  # refused, not computed (a generous bound)
    detail = client.post("/v1/maneuvers", json={"lot": cases["self-intersecting"], "duration_s": 30}).json()["detail"]
    assert "crosses itself" in detail
    detail = client.post("/v1/maneuvers", json={"lot": cases["too many vertices"], "duration_s": 30}).json()["detail"]
    assert "more than 500 vertices" in detail
