"""Every answer of the coordinator, page, file or API, tells the browser what it may load, that
it may not be framed or sniffed, and to send no Referer (a phone's URL carries its pairing
code); and the pages need nothing the policy forbids."""

from __future__ import annotations

import re
from html.parser import HTMLParser

import pytest
from fastapi.testclient import TestClient

from crowdteleop.coord.api.pages import PAGES, STATIC
from crowdteleop.coord.app import create_app
from tests.fixtures.coord import ADMIN, Api, FakeLauncher, coord_config, in_process_app

pytestmark = pytest.mark.filterwarnings("ignore:Using `httpx`")


@pytest.fixture
def client(tmp_path):
    with in_process_app(
        coord_config(tmp_path, capacity=1, max_body_bytes=2048), FakeLauncher()
    ) as c:
        yield c


def _policy(response) -> dict[str, list[str]]:
    header = response.headers["Content-Security-Policy"]
    directives = (part.split() for part in header.split(";") if part.strip())
    return {name: sources for name, *sources in directives}


def _assert_hardened(response) -> None:
    where = f"{response.request.method} {response.request.url.path} ({response.status_code})"
    assert response.headers.get("X-Content-Type-Options") == "nosniff", where
    assert response.headers.get("Referrer-Policy") == "no-referrer", where
    assert response.headers.get("X-Frame-Options") == "DENY", where
    policy = _policy(response)
    assert policy["frame-ancestors"] == ["'none'"], where
    assert policy["script-src"] == ["'self'"], where
    assert policy["object-src"] == ["'none'"], where


def test_pages_files_and_api_answers_all_carry_the_security_headers(client):
    api = Api(client)
    joined = api.join({"PROLIFIC_PID": "5f00aa", "STUDY_ID": "st1", "SESSION_ID": "se1"})
    token = joined["worker_token"]
    sid = api.new_session(token)["session_id"]
    api.wait_state(token, sid, "ready")
    code = client.post(f"/api/sessions/{sid}/pairing", headers=api.auth(token)).json()["code"]
    responses = [client.get(f"/{name}") for name in PAGES]
    responses += [
        client.get("/", follow_redirects=False),
        client.get(f"/phone?code={code}"),
        client.get("/static/join.js"),
        client.get("/static/style.css"),
        client.get("/protocol.json"),
        client.get("/qr.svg", params={"text": "http://testserver/phone?code=ABC234"}),
        client.get("/health"),
        client.get(f"/api/sessions/{sid}", headers=api.auth(token)),
        client.get("/api/admin/overview", headers=api.auth(ADMIN)),
        client.post("/api/pair", json={"code": code}),
        client.get("/api/admin/overview"),  # 401
        client.get("/no/such/page"),  # 404
        client.post("/api/join", json={"params": {"PROLIFIC_PID": "<script>"}}),  # 422
        client.post("/api/join", content=b"{" * 4096),  # 413
        client.post("/internal/episodes", json={}),  # 401
    ]
    statuses = {r.status_code for r in responses}
    assert {200, 307, 401, 404, 413, 422} <= statuses, statuses
    for response in responses:
        _assert_hardened(response)


def test_scripts_and_styles_are_served_with_their_types_so_nosniff_lets_them_run(client):
    files = sorted(p.relative_to(STATIC).as_posix() for p in STATIC.rglob("*") if p.is_file())
    vendored = "vendor/js-aruco2-2.0.0/aruco.js"
    assert vendored in files, "the vendored scripts are served too"
    for name in files:
        response = client.get(f"/static/{name}")
        assert response.status_code == 200, name
        kind = response.headers["content-type"]
        if name.endswith(".js"):
            assert re.match(r"(text|application)/javascript", kind), (name, kind)
        elif name.endswith(".css"):
            assert kind.startswith("text/css"), (name, kind)


def test_an_unexpected_error_still_carries_the_headers(tmp_path):
    app = create_app(coord_config(tmp_path), FakeLauncher())

    @app.get("/fails")
    async def fails() -> None:
        raise RuntimeError("a bug")

    with TestClient(app, raise_server_exceptions=False) as client:
        response = client.get("/fails")
    assert response.status_code == 500 and response.json()["error"] == "internal"
    _assert_hardened(response)


class _Loads(HTMLParser):
    """What a page loads (script, stylesheet, image sources) and whether it has inline script."""

    def __init__(self) -> None:
        super().__init__()
        self.sources: list[str] = []
        self.inline_scripts = 0
        self.handlers: list[str] = []
        self._in_script = False

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        found = dict(attrs)
        self.handlers += [name for name in found if name.startswith("on")]
        source = found.get("src") or (found.get("href") if tag == "link" else None)
        if source:
            self.sources.append(source)
        self._in_script = tag == "script" and not found.get("src")

    def handle_data(self, data: str) -> None:
        if self._in_script and data.strip():
            self.inline_scripts += 1

    def handle_endtag(self, tag: str) -> None:
        self._in_script = False


@pytest.mark.parametrize("name", PAGES)
def test_each_page_loads_only_its_own_origins_files_and_no_inline_script(name):
    page = _Loads()
    page.feed((STATIC / f"{name}.html").read_text())
    assert page.inline_scripts == 0 and page.handlers == [], "script-src 'self' refuses them"
    assert page.sources and all(s.startswith("/") and not s.startswith("//") for s in page.sources)


def test_the_pages_scripts_neither_evaluate_strings_nor_reach_other_origins():
    scripts = {p.name: p.read_text() for p in STATIC.glob("*.js")}
    for forbidden in ("eval(", "new Function", "WebSocket(", "http://", "https://"):
        using = [name for name, text in scripts.items() if forbidden in text]
        assert using == [], f"{using}: the policy's 'self' sources would refuse {forbidden}"
