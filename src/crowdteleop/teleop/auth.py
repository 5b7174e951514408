"""One check for every secret a teleop server is given: the worker's, the phone's, the admin's."""

from __future__ import annotations

import hmac

from aiohttp import web


def token_matches(given: str | None, expected: str | None) -> bool:
    """Constant-time comparison; an unset expected token matches nothing."""
    if not expected or given is None:
        return False
    return hmac.compare_digest(given.encode(), expected.encode())


def bearer_matches(request: web.Request, expected: str | None) -> bool:
    """Whether the request carries ``Authorization: Bearer <expected>``."""
    scheme, _, given = request.headers.get("Authorization", "").partition(" ")
    return scheme == "Bearer" and token_matches(given, expected)
