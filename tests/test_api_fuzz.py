"""Fuzz the OpenAPI schema with schemathesis over HTTP: no 5xx, no response outside the schema.

The server accepts jobs but runs none (EXCITE_WORKERS=0), and its route bounds are small, so
that every generated request is cheap.
"""

from __future__ import annotations

import pytest

schemathesis = pytest.importorskip("schemathesis")
from hypothesis import HealthCheck, settings  # noqa: E402
from schemathesis.checks import (  # noqa: E402
    content_type_conformance,
    not_a_server_error,
    response_headers_conformance,
    response_schema_conformance,
    status_code_conformance,
)

from test_api_support import LiveServer  # noqa: E402

CHECKS = [not_a_server_error, status_code_conformance, content_type_conformance,
          response_schema_conformance, response_headers_conformance]


@pytest.fixture(scope="module")
def fuzz_server(tmp_path_factory):
    srv = LiveServer(tmp_path_factory.mktemp("fuzz"), workers=0, score_workers=2,
                     max_route_duration_s=120, max_route_length_m=2000, max_samples=5000,
                     request_timeout_s=30).start()
    yield srv
    srv.stop()


@pytest.fixture(scope="module")
def api_schema(fuzz_server):
    return schemathesis.openapi.from_url(fuzz_server.url + "/openapi.json")


schema = schemathesis.pytest.from_fixture("api_schema")


@schema.parametrize()
@settings(max_examples=30, deadline=None, derandomize=True,
          suppress_health_check=list(HealthCheck))
def test_openapi_fuzz(case):
    case.call_and_validate(checks=CHECKS, timeout=60)
