"""The API's schema and interactive docs are a map of every endpoint: off unless the
coordinator's `api_docs` option turns them on."""

from __future__ import annotations

import pytest

from crowdteleop.teleop.messages import MAX_EPISODE_DURATION_S, MAX_EPISODE_STEPS
from tests.fixtures.coord import FakeLauncher, coord_config, in_process_app

pytestmark = pytest.mark.filterwarnings("ignore:Using `httpx`")
DOCS = ("/docs", "/redoc", "/openapi.json", "/docs/oauth2-redirect")


def test_schema_and_docs_are_not_served_by_default(tmp_path):
    with in_process_app(coord_config(tmp_path), FakeLauncher()) as client:
        for path in DOCS:
            response = client.get(path)
            assert response.status_code == 404, path
            assert response.json()["error"] == "not_found"
        assert client.get("/join").status_code == 200, "the pages are still there"


def test_api_docs_serves_the_schema_and_docs_with_the_limits_it_enforces(tmp_path):
    config = coord_config(tmp_path, api_docs=True)
    with in_process_app(config, FakeLauncher()) as client:
        for path in DOCS:
            response = client.get(path)
            assert response.status_code == 200, path
            assert response.headers["X-Frame-Options"] == "DENY"
        docs = client.get("/docs")
        assert "swagger-ui" in docs.text
        policy = docs.headers["Content-Security-Policy"]
        assert "https://cdn.jsdelivr.net" in policy, "Swagger UI comes from its CDN"
        assert "frame-ancestors 'none'" in policy
        pages = client.get("/join").headers["Content-Security-Policy"]
        assert "cdn.jsdelivr.net" not in pages, "only the docs get the CDN"
        schema = client.get("/openapi.json").json()
    report = schema["components"]["schemas"]["EpisodeReport"]["properties"]
    assert report["steps"]["maximum"] == MAX_EPISODE_STEPS
    assert report["duration_s"]["maximum"] == MAX_EPISODE_DURATION_S
