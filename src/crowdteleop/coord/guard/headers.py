"""Security headers on every response: what a browser may load, frame, sniff and refer.

The pages (crowdteleop/web/static) are ES modules and a stylesheet from /static, fetch only
their own origin (the API, /protocol.json, /qr.svg; the join page also pings the campaign's
other regions, whose origins `connect-src` then lists) and get video as a WebRTC MediaStream
(`srcObject`, which no fetch directive governs). Their one inline part is style: phone.html's
`<style>` block and a few `style=""` attributes, hence `'unsafe-inline'` for styles only.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from starlette.datastructures import MutableHeaders
from starlette.types import ASGIApp, Message, Receive, Scope, Send


def page_policy(connect_origins: Iterable[str] = ()) -> str:
    """The pages' policy; they may also fetch from `connect_origins` (campaigns' regions)."""
    return "; ".join(
        [
            "default-src 'self'",
            "script-src 'self'",
            "style-src 'self' 'unsafe-inline'",
            "img-src 'self'",
            " ".join(["connect-src 'self'", *connect_origins]),
            "object-src 'none'",
            "base-uri 'none'",
            "form-action 'self'",
            "frame-ancestors 'none'",
        ]
    )


# Swagger UI and ReDoc (only served when CoordConfig.api_docs is on) come from a CDN and start
# with an inline script; the rest of the policy stays.
DOCS_POLICY = "; ".join(
    [
        "default-src 'self'",
        "script-src 'self' 'unsafe-inline' https://cdn.jsdelivr.net",
        "style-src 'self' 'unsafe-inline' https://cdn.jsdelivr.net https://fonts.googleapis.com",
        "font-src 'self' https://fonts.gstatic.com",
        "img-src 'self' data: https://fastapi.tiangolo.com https://cdn.redoc.ly",
        "worker-src 'self' blob:",
        "connect-src 'self'",
        "object-src 'none'",
        "base-uri 'none'",
        "frame-ancestors 'none'",
    ]
)
# no-referrer: a phone's URL carries its pairing code in the query, and no page needs the
# Referer (the API authenticates by bearer token, the study's redirect by its own URL).
COMMON_HEADERS: Mapping[str, str] = {
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "X-Frame-Options": "DENY",
}


def security_headers(docs: bool = False, connect_origins: Iterable[str] = ()) -> dict[str, str]:
    """The headers a response gets (the API docs' own policy with `docs`); pages may also
    fetch from `connect_origins` (the campaigns' regions)."""
    policy = DOCS_POLICY if docs else page_policy(connect_origins)
    return {"Content-Security-Policy": policy, **COMMON_HEADERS}


class SecurityHeadersMiddleware:
    """Adds `security_headers` to every HTTP response that does not set them itself."""

    def __init__(
        self, app: ASGIApp, docs_paths: Iterable[str] = (), connect_origins: Iterable[str] = ()
    ) -> None:
        self.app, self.docs_paths = app, frozenset(docs_paths)
        self.page_headers = security_headers(connect_origins=connect_origins)  # made once
        self.docs_headers = security_headers(docs=True)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        docs = scope.get("path", "") in self.docs_paths
        extra = self.docs_headers if docs else self.page_headers

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = MutableHeaders(scope=message)
                for name, value in extra.items():
                    headers.setdefault(name, value)
            await send(message)

        await self.app(scope, receive, send_with_headers)
