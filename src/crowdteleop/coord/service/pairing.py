"""Pairing a phone with a worker's session: a short single-use code (typed, or in the QR code's
URL with a long key), traded once for a phone token."""

from __future__ import annotations

import time
from dataclasses import dataclass

from crowdteleop.coord.db.store import Store
from crowdteleop.coord.db.tables import Session
from crowdteleop.coord.guard.errors import ApiError
from crowdteleop.coord.guard.security import new_pairing_code, new_token, normalize_pairing_code
from crowdteleop.coord.service.config import CoordConfig

DRAWS = 20  # codes drawn before giving up on finding a free one


@dataclass(frozen=True)
class PairingCode:
    code: str
    expires_s: float
    phone_url: str  # the QR code's: the code and its key


class Pairing:
    def __init__(self, store: Store, config: CoordConfig) -> None:
        self._pairing, self._config = store.pairing, config

    async def new_code(self, session: Session) -> PairingCode:
        """A fresh single-use code for `session`'s phone; earlier codes stay valid until used
        or expired."""
        if session.state == "ended":
            raise ApiError(409, "ended", "the session has ended")
        ttl = self._config.pairing_ttl_s
        key = new_token()  # the QR link's: typing it is not expected, guessing it is hopeless
        for _ in range(DRAWS):
            code = new_pairing_code()
            if await self._pairing.add_code(session.id, code, time.time() + ttl, key):
                break
        else:
            raise ApiError(409, "busy", "could not draw a free code; try again")
        base = self._config.public_url.rstrip("/")
        return PairingCode(code, ttl, f"{base}/phone?code={code}&key={key}")

    async def redeem(self, code: str, key: str | None = None) -> tuple[str, str] | None:
        """(session id, phone token) for a live code, which is used up; else None. With the
        QR link's `key`, the code must be the one it was made with."""
        return await self._pairing.redeem(normalize_pairing_code(code), time.time(), key=key)

    async def session_of_phone(self, phone_token: str) -> Session | None:
        return await self._pairing.session_of_phone(phone_token)
