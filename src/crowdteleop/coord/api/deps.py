"""FastAPI dependencies: the app's coordinator, and who is asking (worker, phone, admin)."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Path, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from crowdteleop.coord.db.tables import Session, Worker
from crowdteleop.coord.guard.errors import ApiError
from crowdteleop.coord.guard.security import same
from crowdteleop.coord.service.coordinator import Coordinator
from crowdteleop.coord.service.guards import Guards

bearer_scheme = HTTPBearer(auto_error=False, description="worker, phone, admin or report token")
Credentials = Annotated[HTTPAuthorizationCredentials | None, Depends(bearer_scheme)]
SessionId = Annotated[str, Path(pattern=r"^s_[0-9a-f]{16}$", description="a session id")]


def get_coordinator(request: Request) -> Coordinator:
    coordinator: Coordinator = request.app.state.coordinator  # set by create_app
    return coordinator


CoordinatorDep = Annotated[Coordinator, Depends(get_coordinator)]


def get_guards(request: Request) -> Guards:
    guards: Guards = request.app.state.guards  # set by create_app
    return guards


GuardsDep = Annotated[Guards, Depends(get_guards)]


def get_client(request: Request, guards: GuardsDep) -> str:
    """The client address key this request is counted under (coord/guard/clients.py)."""
    return guards.client(request)


ClientDep = Annotated[str, Depends(get_client)]


def token_of(credentials: HTTPAuthorizationCredentials | None) -> str | None:
    if credentials is None or not credentials.credentials or len(credentials.credentials) > 512:
        return None
    return credentials.credentials


async def worker_for(coordinator: Coordinator, token: str | None) -> Worker:
    worker, revoked = await coordinator.store.token_holder(token) if token else (None, False)
    if revoked:
        raise ApiError(
            401,
            "taken_over",
            "Your session was taken over in another browser. Open the study link again to "
            "take it back.",
        )
    if worker is None:
        raise ApiError(401, "unauthorized", "a valid worker token is required (from /api/join)")
    return worker


async def current_worker(coordinator: CoordinatorDep, credentials: Credentials) -> Worker:
    return await worker_for(coordinator, token_of(credentials))


WorkerDep = Annotated[Worker, Depends(current_worker)]


async def owned(coordinator: Coordinator, session_id: str, worker: Worker) -> Session:
    """The session if it is this worker's; 404 otherwise (others' ids are not confirmed)."""
    session = await coordinator.store.session(session_id)
    if session is None or session.worker_id != worker.id:
        raise ApiError(404, "not_found", "no such session")
    return session


async def owned_session(
    session_id: SessionId, coordinator: CoordinatorDep, worker: WorkerDep
) -> Session:
    return await owned(coordinator, session_id, worker)


OwnedSession = Annotated[Session, Depends(owned_session)]


async def require_admin(
    coordinator: CoordinatorDep, credentials: Credentials, guards: GuardsDep, client: ClientDep
) -> None:
    """The admin token, with wrong guesses limited per address (429 past the limit)."""
    guards.check_admin(client)
    token = token_of(credentials)
    if token is None or not same(token, coordinator.config.admin_token):
        guards.admin_failed(client)
        raise ApiError(401, "unauthorized", "the admin token is required")


async def phone_session(coordinator: CoordinatorDep, credentials: Credentials) -> Session:
    token = token_of(credentials)
    session = await coordinator.store.pairing.session_of_phone(token) if token else None
    if session is None:
        raise ApiError(401, "unauthorized", "a valid phone token is required (from /api/pair)")
    return session


PhoneSession = Annotated[Session, Depends(phone_session)]
