"""Which browser origins a teleop server takes requests from: none but its own and the
coordinator's; servers and bots, which send no Origin, always."""

from __future__ import annotations

from aiohttp.test_utils import make_mocked_request

from crowdteleop.teleop.origin import normalize_origin, origin_allowed

COORDINATOR = "https://coord.example:8443/join"


def request(origin: str | None):
    headers = {"Host": "127.0.0.1:5000", **({"Origin": origin} if origin is not None else {})}
    return make_mocked_request("POST", "/offer", headers=headers)


def test_origins_compare_by_scheme_host_and_port():
    assert normalize_origin("HTTPS://Coord.Example:443") == "https://coord.example"
    assert normalize_origin("http://[::1]:8000/x") == "http://[::1]:8000"
    assert normalize_origin("null") is None
    assert normalize_origin("file:///etc") is None


def test_no_origin_our_own_and_the_coordinators_are_taken():
    assert origin_allowed(request(None), [COORDINATOR]), "the coordinator's proxy, bots"
    assert origin_allowed(request("http://127.0.0.1:5000"), [COORDINATOR])
    assert origin_allowed(request("https://coord.example:8443"), [COORDINATOR])


def test_a_foreign_page_is_refused():
    assert not origin_allowed(request("https://evil.example"), [COORDINATOR])
    assert not origin_allowed(request("http://coord.example:8443"), [COORDINATOR]), "scheme"
    assert not origin_allowed(request("http://127.0.0.1:5001"), [COORDINATOR]), "port"
    assert not origin_allowed(request("null"), [COORDINATOR])
