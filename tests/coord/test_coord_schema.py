"""Property-based fuzzing of the HTTP API from its own OpenAPI schema (schemathesis): whatever
arrives, valid or not, the answer is never a 5xx, and every error has the documented shape."""

from __future__ import annotations

import time

import httpx
import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from schemathesis import GenerationMode

from crowdteleop.coord.app import create_app
from tests.fixtures.coord import ADMIN, FakeLauncher, coord_config, served_app

pytestmark = pytest.mark.slow


@pytest.fixture
def live_app(tmp_path):
    """The app served by uvicorn in a thread, with a worker whose session is ready (and its
    schema served: `api_docs` is off by default)."""
    launcher = FakeLauncher()
    app = create_app(coord_config(tmp_path, capacity=2, api_docs=True), launcher)
    with served_app(app) as url, httpx.Client(base_url=url, timeout=30) as http:
        token = http.post("/api/join", json={"params": {}}).json()["worker_token"]
        headers = {"Authorization": f"Bearer {token}"}
        sid = http.post("/api/sessions", headers=headers).json()["session_id"]
        code = http.post(f"/api/sessions/{sid}/pairing", headers=headers).json()["code"]
        phone = http.post("/api/pair", json={"code": code}).json()["phone_token"]
        while sid not in launcher.handles:
            time.sleep(0.05)
        report = launcher.handles[sid].config.report_token
        schema = http.get("/openapi.json").json()
        tokens = {"worker": token, "phone": phone, "admin": ADMIN, "report": report}
        yield url, schema, sid, tokens


def _token_for(path: str, tokens: dict[str, str]) -> str:
    if path.startswith("/api/admin"):
        return tokens["admin"]
    if path.startswith("/api/phone"):
        return tokens["phone"]
    if path.startswith("/internal"):
        return tokens["report"]
    return tokens["worker"]


def test_no_input_makes_the_api_fail_with_a_5xx(live_app):
    url, raw_schema, sid, tokens = live_app
    schema = schemathesis.openapi.from_dict(raw_schema)
    cases = st.one_of(
        schema.as_strategy(generation_mode=GenerationMode.POSITIVE),
        schema.as_strategy(generation_mode=GenerationMode.NEGATIVE),
    )
    seen: dict[int, int] = {}

    @settings(
        max_examples=400,
        deadline=None,
        database=None,
        suppress_health_check=list(HealthCheck),
    )
    @given(case=cases, real_session=st.booleans(), authorized=st.booleans())
    def fuzz(case, real_session, authorized):
        if real_session and "session_id" in (case.path_parameters or {}):
            case.path_parameters["session_id"] = sid
        if authorized:  # a real token of the kind the endpoint wants, else whatever was drawn
            token = _token_for(case.operation.path, tokens)
            case.headers = {**(case.headers or {}), "Authorization": f"Bearer {token}"}
        response = case.call(base_url=url)
        seen[response.status_code] = seen.get(response.status_code, 0) + 1
        assert response.status_code < 500, (case.method, case.formatted_path, response.text)
        if response.status_code >= 400:
            body = response.json()
            assert set(body) == {"error", "message"}, body

    fuzz()
    assert any(200 <= status < 300 for status in seen), seen
    assert any(400 <= status < 500 for status in seen), seen
