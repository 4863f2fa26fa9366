"""Fuzz the OpenAPI schema with schemathesis over HTTP, with every check schemathesis has
(``--checks all``): no 5xx, no response outside the schema, invalid data rejected, unsupported
methods answered 405 with ``Allow``.

One check is configured: schema-valid bodies may be refused with 422 (positive data acceptance).
JSON Schema cannot state that waypoints must not repeat, that sensor rates must divide the
keyframe rate, or that a route must last long enough to score; the service says so in a 422.
Every *bound* the service enforces is in the schema, which tests/api/test_serving.py checks
on its own. The server accepts jobs but runs none (EXCITE_WORKERS=0), and its route bounds are
small, so that every generated request is cheap.
"""

from __future__ import annotations

import pytest

schemathesis = pytest.importorskip("schemathesis")
from hypothesis import HealthCheck, settings  # noqa: E402
from schemathesis.config import SchemathesisConfig  # noqa: E402

from servers import LiveServer  # noqa: E402

@pytest.fixture(scope="module")
def fuzz_server(tmp_path_factory):
    srv = LiveServer(tmp_path_factory.mktemp("fuzz"), workers=0, score_workers=2,
                     max_route_duration_s=120, max_route_length_m=2000, max_samples=5000,
                     request_timeout_s=30).start()
    yield srv
    srv.stop()


@pytest.fixture(scope="module")
def api_schema(fuzz_server):
    config = SchemathesisConfig.from_dict({"checks": {"positive_data_acceptance": {
        "expected-statuses": ["2xx", "401", "403", "404", "409", "422"]}}})
    return schemathesis.openapi.from_url(fuzz_server.url + "/openapi.json", config=config)


schema = schemathesis.pytest.from_fixture("api_schema")


@pytest.mark.slow
@schema.parametrize()
@settings(max_examples=30, deadline=None, derandomize=True,
          suppress_health_check=list(HealthCheck))
def test_openapi_fuzz(case):
    case.call_and_validate(timeout=60)  # every check
