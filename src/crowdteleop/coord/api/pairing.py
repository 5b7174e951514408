"""Pairing a phone with a worker's session through a short code (or the QR code's URL)."""

from __future__ import annotations

import time
from typing import Any

from fastapi import APIRouter, Request

from crowdteleop.coord.api.deps import (
    ClientDep,
    CoordinatorDep,
    GuardsDep,
    OwnedSession,
    PhoneSession,
)
from crowdteleop.coord.api.schemas import (
    ErrorBody,
    OfferBody,
    PairingView,
    PairRequest,
    PairResponse,
    PhoneSessionView,
)
from crowdteleop.coord.fleet.teleop_http import forward_offer
from crowdteleop.coord.guard.errors import ApiError
from crowdteleop.coord.guard.security import new_pairing_code, new_token, normalize_pairing_code
from crowdteleop.tasks import get_task
from crowdteleop.teleop.messages import OfferAnswer

ERRORS: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorBody} for code in (401, 404, 409, 422, 429)
}
router = APIRouter(prefix="/api", tags=["phone"], responses=ERRORS)


@router.post("/sessions/{session_id}/pairing", response_model=PairingView)
async def new_pairing(session: OwnedSession, coordinator: CoordinatorDep) -> PairingView:
    """A fresh single-use code for this session's phone; earlier codes stay valid until used
    or expired."""
    if session.state == "ended":
        raise ApiError(409, "ended", "the session has ended")
    ttl = coordinator.config.pairing_ttl_s
    key = new_token()  # the QR link's: typing it is not expected, guessing it is hopeless
    for _ in range(20):
        code = new_pairing_code()
        if await coordinator.store.pairing.add_code(session.id, code, time.time() + ttl, key):
            break
    else:
        raise ApiError(409, "busy", "could not draw a free code; try again")
    base = coordinator.config.public_url.rstrip("/")
    return PairingView(code=code, expires_s=ttl, phone_url=f"{base}/phone?code={code}&key={key}")


@router.post("/pair", response_model=PairResponse)
async def pair(
    body: PairRequest, coordinator: CoordinatorDep, guards: GuardsDep, client: ClientDep
) -> PairResponse:
    """Trade a code for a phone token. Wrong, expired or used codes: 404. A typed code is
    refused (429) after too many wrong ones from the client's address or from everyone; the
    QR link's code with its long key never is."""
    code = normalize_pairing_code(body.code)
    if body.key:
        redeemed = await coordinator.store.pairing.redeem(code, time.time(), key=body.key)
    else:
        await guards.check_pairing(client)
        redeemed = await coordinator.store.pairing.redeem(code, time.time())
    if redeemed is None:
        await guards.pairing_failed(client)
        raise ApiError(404, "bad_code", "that code is wrong, expired or already used")
    session_id, token = redeemed
    session = await coordinator.store.session(session_id)
    if session is None or session.state == "ended":
        raise ApiError(404, "bad_code", "that code's session has ended")
    return PairResponse(phone_token=token, session_id=session_id)


@router.get("/phone/session", response_model=PhoneSessionView)
async def phone_session(session: PhoneSession, coordinator: CoordinatorDep) -> PhoneSessionView:
    """What the phone page shows: the task and whether the robot is ready."""
    return PhoneSessionView(
        session_id=session.id,
        state=session.state,
        task=session.task,
        instruction=get_task(session.task).instruction,
        ended_reason=session.ended_reason,
        ice_servers=coordinator.configs.ice_servers(f"{session.id}-phone"),
        ice_transport_policy=coordinator.config.ice_transport_policy,
    )


@router.post("/phone/offer", response_model=OfferAnswer)
async def phone_offer(body: OfferBody, session: PhoneSession, request: Request) -> OfferAnswer:
    """WebRTC offer from the paired phone (role phone: data channels only, no video)."""
    token = request.app.state.coordinator.keys.teleop_token(session.id)
    return await forward_offer(request.app.state.http, session, token, body, "phone")
