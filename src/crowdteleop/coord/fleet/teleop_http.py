"""The teleop server's HTTP API as the coordinator calls it: a worker's or phone's WebRTC offer
(forwarded with the session's token, which the browser never learns), a warm spare's
assignment (`POST /assign`), and the health probe (`GET /health`)."""

from __future__ import annotations

import logging

import aiohttp

from crowdteleop.coord.db.tables import Session
from crowdteleop.coord.fleet.launcher import LaunchError
from crowdteleop.coord.guard.errors import ApiError
from crowdteleop.teleop.messages import (
    Assignment,
    OfferAnswer,
    OfferRequest,
    TeleopHealth,
    missing_offer_sections,
)
from crowdteleop.teleop.protocol import PeerRole

log = logging.getLogger(__name__)

OFFER_TIMEOUT_S = 20.0


async def forward_offer(
    http: aiohttp.ClientSession, session: Session, token: str, sdp: str, role: PeerRole
) -> OfferAnswer:
    """POST the offer with the session's teleop `token` (`SessionKeys.teleop_token`) to its
    teleop server; its refusals come back as 4xx. No `Origin` header: a server-to-server call,
    which the teleop server's origin check lets through."""
    if session.state != "ready" or not session.teleop_url:
        raise ApiError(409, "not_ready", f"the session is {session.state}, not ready")
    missing = missing_offer_sections(sdp, role)
    if missing:  # refused here as the teleop server would: no round trip, no peer
        raise ApiError(400, "incomplete_offer", f"the offer has no {' or '.join(missing)} section")
    body = OfferRequest(sdp=sdp, token=token, role=role)
    try:
        async with http.post(
            f"{session.teleop_url}/offer",
            data=body.model_dump_json(),
            headers={"Content-Type": "application/json"},
            timeout=aiohttp.ClientTimeout(total=OFFER_TIMEOUT_S),
        ) as response:
            payload = await response.json(content_type=None)
            status = response.status
    except (aiohttp.ClientError, TimeoutError, ValueError) as exc:
        log.warning("offer to %s failed: %s", session.teleop_url, exc)
        raise ApiError(409, "teleop_unavailable", "the robot's server did not answer") from exc
    if status == 200 and isinstance(payload, dict):
        try:
            return OfferAnswer.model_validate(payload)
        except ValueError as exc:
            raise ApiError(409, "teleop_unavailable", "the robot's server answered oddly") from exc
    code = payload.get("error", "offer_refused") if isinstance(payload, dict) else "offer_refused"
    message = payload.get("message", "") if isinstance(payload, dict) else ""
    if status == 400:
        raise ApiError(400, str(code), str(message) or "the offer was refused")
    # 401/403 would be our own token being wrong, 503 a full session: neither is the caller's
    # input, so both say the session cannot take this connection now.
    raise ApiError(409, str(code), str(message) or f"the robot's server refused ({status})")


async def assign(url: str, admin_token: str, assignment: Assignment) -> None:
    """Give a warm spare its session (`LaunchError` if it refuses)."""
    headers = {"Authorization": f"Bearer {admin_token}", "Content-Type": "application/json"}
    timeout = aiohttp.ClientTimeout(total=10)
    async with (
        aiohttp.ClientSession(timeout=timeout) as http,
        http.post(f"{url}/assign", data=assignment.model_dump_json(), headers=headers) as response,
    ):
        if response.status != 200:
            raise LaunchError(f"assign answered {response.status}: {await response.text()}")


async def health(http: aiohttp.ClientSession, url: str, timeout_s: float) -> TeleopHealth | None:
    """The server's health, or None without a good answer in time."""
    try:
        timeout = aiohttp.ClientTimeout(total=timeout_s)
        async with http.get(f"{url}/health", timeout=timeout) as response:
            if response.status != 200:
                return None
            return TeleopHealth.model_validate_json(await response.read())
    except (aiohttp.ClientError, TimeoutError, ValueError):  # ValidationError is a ValueError
        return None
