"""Time-limited TURN credentials, the TURN REST API scheme coturn implements
(`use-auth-secret` with `static-auth-secret`): the username is "<expiry unix time>:<name>"
and the password base64(HMAC-SHA1(secret, username)). The coordinator and the TURN server
share only the secret; each session (and each teleop server) gets its own credentials, which
stop working at their expiry, so a leaked one is worth little."""

from __future__ import annotations

import base64
import hashlib
import hmac

from pydantic import BaseModel, ConfigDict, Field

from crowdteleop.teleop.messages import IceServer


class TurnConfig(BaseModel):
    """A TURN server (coturn) that takes REST API credentials; docs/security.md, "TURN"."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    urls: list[str] = Field(min_length=1, description="e.g. turn:turn.example.org:3478")
    secret: str = Field(min_length=16, max_length=256, description="coturn's static-auth-secret")
    ttl_s: float = Field(
        6 * 3600, gt=0, le=7 * 24 * 3600, description="how long each credential stays valid"
    )


def turn_credentials(turn: TurnConfig, name: str, now: float) -> IceServer:
    """Credentials for `name` (a session or a teleop server) valid until `now + ttl_s`."""
    username = f"{int(now + turn.ttl_s)}:{name}"
    digest = hmac.new(turn.secret.encode(), username.encode(), hashlib.sha1).digest()
    return IceServer(
        urls=list(turn.urls), username=username, credential=base64.b64encode(digest).decode()
    )
