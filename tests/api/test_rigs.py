"""POST /v1/rigs/parse: YAML built to cost the server — nested deep, or a long flow list — is a
422 in well under a second of a worker's time, never a 500 or a traceback in the log."""

from __future__ import annotations

import time

import pytest
from fastapi.testclient import TestClient

from api import Settings, create_app


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("rigs")
    app = create_app(Settings(db_path=tmp / "jobs.sqlite3", workers=0, score_workers=1))
    with TestClient(app, base_url="http://localhost", raise_server_exceptions=False) as c:
        yield c


def _timed(c, yaml_text: str):
    t0 = time.monotonic()
    r = c.post("/v1/rigs/parse", json={"yaml": yaml_text})
    return r, time.monotonic() - t0


def test_nested_yaml_is_422_fast(client, caplog):
    r, s = _timed(client, "a: " + "[" * 5000 + "]" * 5000)  # 10 KB
    assert r.status_code == 422 and "nested" in r.json()["detail"], r.text[:300]
    assert s < 3.0
    r, s = _timed(client, "\n".join(" " * i + "a:" for i in range(0, 4000, 2)))  # block mappings
    assert r.status_code == 422 and s < 3.0
    assert "Traceback" not in caplog.text


def test_a_long_flow_list_is_422_fast(client):
    r, s = _timed(client, "imu: [" + ",".join(["1"] * 99_000) + "]")  # ~198 KB, under the size bound
    assert r.status_code == 422 and "values" in r.json()["detail"], r.text[:300]
    assert s < 3.0
    r, _ = _timed(client, "imu: [" + ",".join(["1"] * 330_000) + "]")  # 660 KB: over the size bound
    assert r.status_code == 422 and r.json()["errors"][0]["field"] == "yaml"


def test_a_rig_file_still_parses(client):
    import yaml as pyyaml

    from excite.rig.config import RIGS_DIR

    r = client.post("/v1/rigs/parse", json={"yaml": (RIGS_DIR / "robotaxi.yaml").read_text()})
    assert r.status_code == 200, r.text[:300]
    assert r.json()["summary"]["name"] == pyyaml.safe_load((RIGS_DIR / "robotaxi.yaml").read_text())["name"]


def test_the_parse_response_is_accepted_as_it_is_where_a_rig_is_expected(client):
    """POST /v1/rigs/parse answers {"rig": …, "summary": …}: that answer, passed on as `rig`,
    scores as the rig it holds."""
    from excite.rig.config import RIGS_DIR

    parsed = client.post("/v1/rigs/parse", json={"yaml": (RIGS_DIR / "robotaxi.yaml").read_text()}).json()
    route = {"waypoints": [[0, 0], [30, 0], [30, 20], [0, 20], [0, 1]]}
    as_is = client.post("/v1/score", json={"route": route, "rig": parsed})
    unwrapped = client.post("/v1/score", json={"route": route, "rig": parsed["rig"]})
    assert as_is.status_code == 200, as_is.text[:300]
    assert as_is.json()["score"] == unwrapped.json()["score"]
    assert as_is.json()["rig"] == parsed["summary"]["name"]


def test_another_tools_file_is_named_with_its_importer(client, data_dir):
    text = (data_dir / "rig_files" / "lio_sam" / "params.yaml").read_text()
    r = client.post("/v1/rigs/parse", json={"yaml": text})
    assert r.status_code == 422
    assert "this is a LIO-SAM file, not a rig: `excite rig from-lio-sam FILE`" in r.json()["detail"]
    text = (data_dir / "rig_files" / "vins_fusion" / "euroc_stereo_imu_config.yaml").read_text()  # %YAML:1.0
    r = client.post("/v1/rigs/parse", json={"yaml": text})
    assert r.status_code == 422 and "excite rig from-vins FILE" in r.json()["detail"]
