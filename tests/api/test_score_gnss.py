"""The service scores a rig with a GNSS antenna as the library does."""

from __future__ import annotations

import pytest
from excite.motion.maneuvers import figure_eight
from excite.motion.vehicle import drive
from excite.score.evaluate import evaluate
from helpers import gnss_rig, sigmas


@pytest.fixture(scope="module")
def rig():
    return gnss_rig(lidar=True)


@pytest.fixture(scope="module")
def traj(rig):
    return drive(figure_eight(40.0), rig.suspension)


@pytest.mark.slow
def test_the_service_scores_a_rig_with_gnss(tmp_path, rig, traj):
    """The HTTP service takes the rig as it takes any (a new kind needs no change there): the
    report's σ are the library's."""
    from excite.io.routes import write_tum
    from servers import LiveServer

    rig_dict = rig.config.model_dump(mode="json")
    tum = write_tum(traj, tmp_path / "eight.tum")
    (tmp_path / "srv").mkdir()
    srv = LiveServer(tmp_path / "srv", workers=1, score_workers=1, max_job_time_budget_s=60).start()
    try:
        with srv.client() as c:
            r = c.post("/v1/score", json={"route": {"name": "eight", "format": "tum", "text": tum.read_text()},
                                          "rig": rig_dict})
    finally:
        srv.stop()
    assert r.status_code == 200, r.text
    got = {p["name"]: p["sigma"] for p in r.json()["parameters"]}
    from excite.io.routes import read_route

    want = sigmas(evaluate(read_route(tum), rig))
    for n in ("gnss.trans_x", "gnss.trans_y", "gnss.time_offset"):
        assert got[n] == pytest.approx(want[n], rel=1e-9), n
