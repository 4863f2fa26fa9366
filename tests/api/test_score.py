"""POST /v1/score with a bag upload (multipart): scored like the library, bad bags are 422
problem+json, bodies over the limit 413."""

from __future__ import annotations

import pytest

from excite.io.bags import BagSource
from excite.score.evaluate import evaluate
from excite.rig.config import load_rig
from excite.io.routes import read_route
from servers import LiveServer

NAV2 = "nav2_turtlebot.mcap"
LIMIT = 1024 * 1024


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    srv = LiveServer(tmp_path_factory.mktemp("bags"), workers=0, score_workers=1,
                     max_body_bytes=LIMIT).start()
    yield srv
    srv.stop()


def _post(server, name, data, **fields):
    with server.client() as c:
        return c.post("/v1/score/bag", files={"bag": (name, data, "application/octet-stream")}, data=fields,
                      headers={"X-Excite-Client": "tests"})


@pytest.mark.slow
def test_uploaded_bag_scores_like_the_library(server, data_dir):
    data = (data_dir / NAV2).read_bytes()
    r = _post(server, NAV2, data, topic="/tf:odom.base_link", rig="robotaxi")
    assert r.status_code == 200, r.text
    rep = r.json()
    expected = evaluate(read_route(data_dir / NAV2, bag=BagSource("/tf:odom.base_link")), load_rig("robotaxi"))
    assert rep["score"] == pytest.approx(expected.score, rel=1e-9, abs=1e-15)
    assert rep["route"] == f"{NAV2}:/tf:odom.base_link"
    assert [p["sigma"] is None for p in rep["parameters"]] == [p.sigma is None for p in expected.parameters]


def test_truncated_bag_and_missing_fields_are_422(server, data_dir):
    data = (data_dir / NAV2).read_bytes()
    r = _post(server, NAV2, data[: len(data) // 2], topic="/odom")
    assert r.status_code == 422 and r.headers["content-type"].startswith("application/problem+json")
    body = r.json()
    assert "truncated or corrupt" in body["detail"] and "/tmp" not in body["detail"]
    assert body["errors"][0]["field"] == "bag"
    r = _post(server, NAV2, data, topic="/nope")
    assert r.status_code == 422 and "/odom" in r.json()["detail"]
    r = _post(server, NAV2, data)
    assert r.status_code == 422 and r.json()["errors"][0]["field"] == "topic"
    r = _post(server, "drive.txt", data, topic="/odom")
    assert r.status_code == 422 and r.json()["errors"][0]["field"] == "bag"


def test_upload_over_the_body_limit_is_413(server):
    r = _post(server, "big.mcap", b"\0" * (LIMIT + 1), topic="/odom")
    assert r.status_code == 413 and r.headers["content-type"].startswith("application/problem+json")


def test_json_score_requests_still_take_the_json_route(server):
    with server.client() as c:
        r = c.post("/v1/score", json={"route": {"format": "tum", "text": "nonsense"}})
    assert r.status_code == 422 and r.headers["content-type"].startswith("application/problem+json")
