"""Which browser origins may call a teleop server's HTTP signalling.

No page talks to a teleop server directly: the worker's and the phone's pages send their offers
to the coordinator, which forwards them server to server (no `Origin` header), and bots
(`crowdteleop.client`) send none either. A request that carries an `Origin` comes from a browser;
it is let through only from the server's own origin or one the config names (the coordinator's
public URL), so a hostile page cannot spend a session's peer slots with a leaked token.
"""

from __future__ import annotations

from urllib.parse import urlsplit

from aiohttp import web

DEFAULT_PORTS = {"http": 80, "https": 443}


def normalize_origin(value: str) -> str | None:
    """`scheme://host[:port]` in lower case, default port left out; None if not an origin."""
    try:
        parts = urlsplit(value.strip())
        port = parts.port
    except ValueError:
        return None
    if parts.scheme not in DEFAULT_PORTS or not parts.hostname:
        return None
    host = f"[{parts.hostname}]" if ":" in parts.hostname else parts.hostname
    shown = "" if port in (None, DEFAULT_PORTS[parts.scheme]) else f":{port}"
    return f"{parts.scheme}://{host.lower()}{shown}"


def origin_allowed(request: web.Request, allowed: list[str]) -> bool:
    """No `Origin` (a server or a bot), our own, or one of `allowed` (origins or URLs)."""
    given = request.headers.get("Origin")
    if given is None:
        return True
    origin = normalize_origin(given)  # "null" (sandboxed pages, file://) is never allowed
    if origin is None:
        return False
    own = normalize_origin(f"{request.scheme}://{request.host}")
    return origin == own or origin in {normalize_origin(a) for a in allowed}
