"""The doors into a session's teleop server: WebRTC offers from the worker's page and phone,
forwarded with the session's token (which no browser learns), and the server's address and
tokens for a privileged bot (the admin API)."""

from __future__ import annotations

from dataclasses import dataclass

import aiohttp

from crowdteleop.coord.db.tables import Session
from crowdteleop.coord.fleet.teleop_http import forward_offer
from crowdteleop.coord.guard.errors import ApiError
from crowdteleop.coord.guard.session_keys import SessionKeys
from crowdteleop.teleop.messages import OfferAnswer
from crowdteleop.teleop.protocol import PeerRole


@dataclass(frozen=True)
class TeleopDoor:
    url: str
    token: str
    admin_token: str


class Signaling:
    """Made inside the app's lifespan (it holds an HTTP client); `close` it there."""

    def __init__(self, keys: SessionKeys) -> None:
        self._keys = keys
        self._http = aiohttp.ClientSession()

    async def offer(self, session: Session, sdp: str, role: PeerRole) -> OfferAnswer:
        """The session's teleop server's answer (409 until it is ready)."""
        return await forward_offer(
            self._http, session, self._keys.teleop_token(session.id), sdp, role
        )

    def door(self, session: Session) -> TeleopDoor:
        """The session's teleop server URL and tokens (409 until it is ready)."""
        if session.state != "ready" or not session.teleop_url:
            raise ApiError(409, "not_ready", f"the session is {session.state}, not ready")
        return TeleopDoor(
            url=session.teleop_url,
            token=self._keys.teleop_token(session.id),
            admin_token=self._keys.teleop_admin_token(session.id),
        )

    async def close(self) -> None:
        await self._http.close()
