"""Pairing a phone with a worker's session through a short code (or the QR code's URL)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from crowdteleop.coord.api.deps import (
    ClientDep,
    ConfigDep,
    CoordinatorDep,
    GuardsDep,
    OwnedSession,
    PairingDep,
    PhoneSession,
    SignalingDep,
)
from crowdteleop.coord.api.schemas import (
    ErrorBody,
    OfferBody,
    PairingView,
    PairRequest,
    PairResponse,
    PhoneSessionView,
)
from crowdteleop.coord.guard.errors import ApiError
from crowdteleop.tasks import get_task
from crowdteleop.teleop.messages import OfferAnswer

ERRORS: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorBody} for code in (401, 404, 409, 422, 429)
}
router = APIRouter(prefix="/api", tags=["phone"], responses=ERRORS)


@router.post("/sessions/{session_id}/pairing", response_model=PairingView)
async def new_pairing(session: OwnedSession, pairing: PairingDep) -> PairingView:
    """A fresh single-use code for this session's phone; earlier codes stay valid until used
    or expired."""
    new = await pairing.new_code(session)
    return PairingView(code=new.code, expires_s=new.expires_s, phone_url=new.phone_url)


@router.post("/pair", response_model=PairResponse)
async def pair(
    body: PairRequest,
    pairing: PairingDep,
    coordinator: CoordinatorDep,
    guards: GuardsDep,
    client: ClientDep,
) -> PairResponse:
    """Trade a code for a phone token. Wrong, expired or used codes: 404. A typed code is
    refused (429) after too many wrong ones from the client's address or from everyone; the
    QR link's code with its long key never is."""
    if body.key:
        redeemed = await pairing.redeem(body.code, key=body.key)
    else:
        await guards.check_pairing(client)
        redeemed = await pairing.redeem(body.code)
    if redeemed is None:
        await guards.pairing_failed(client)
        raise ApiError(404, "bad_code", "that code is wrong, expired or already used")
    session_id, token = redeemed
    session = await coordinator.session(session_id)
    if session is None or session.state == "ended":
        raise ApiError(404, "bad_code", "that code's session has ended")
    return PairResponse(phone_token=token, session_id=session_id)


@router.get("/phone/session", response_model=PhoneSessionView)
async def phone_session(
    session: PhoneSession, coordinator: CoordinatorDep, config: ConfigDep
) -> PhoneSessionView:
    """What the phone page shows: the task and whether the robot is ready."""
    return PhoneSessionView(
        session_id=session.id,
        state=session.state,
        task=session.task,
        instruction=get_task(session.task).instruction,
        ended_reason=session.ended_reason,
        ice_servers=coordinator.ice_servers(f"{session.id}-phone"),
        ice_transport_policy=config.ice_transport_policy,
    )


@router.post("/phone/offer", response_model=OfferAnswer)
async def phone_offer(
    body: OfferBody, session: PhoneSession, signaling: SignalingDep
) -> OfferAnswer:
    """WebRTC offer from the paired phone (role phone: data channels only, no video)."""
    return await signaling.offer(session, body.sdp, "phone")
