"""FastAPI dependencies: the services the lifespan put on `app.state`, and who is asking
(worker, phone, admin)."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Path, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from crowdteleop.coord.db.tables import Session, Worker
from crowdteleop.coord.guard.errors import ApiError
from crowdteleop.coord.guard.security import same
from crowdteleop.coord.service.completion import Completion
from crowdteleop.coord.service.config import CoordConfig
from crowdteleop.coord.service.coordinator import Coordinator
from crowdteleop.coord.service.episodes import Episodes
from crowdteleop.coord.service.guards import Guards
from crowdteleop.coord.service.history import History
from crowdteleop.coord.service.metrics import CoordMetrics
from crowdteleop.coord.service.pairing import Pairing
from crowdteleop.coord.service.reputation import WorkerRecords
from crowdteleop.coord.service.signaling import Signaling
from crowdteleop.coord.service.workers import Workers

bearer_scheme = HTTPBearer(auto_error=False, description="worker, phone, admin or report token")
Credentials = Annotated[HTTPAuthorizationCredentials | None, Depends(bearer_scheme)]
SessionId = Annotated[str, Path(pattern=r"^s_[0-9a-f]{16}$", description="a session id")]


# --- the services (set by create_app's lifespan) ---------------------------------------------


def get_config(request: Request) -> CoordConfig:
    config: CoordConfig = request.app.state.config
    return config


def get_coordinator(request: Request) -> Coordinator:
    coordinator: Coordinator = request.app.state.coordinator
    return coordinator


def get_workers(request: Request) -> Workers:
    workers: Workers = request.app.state.workers
    return workers


def get_pairing(request: Request) -> Pairing:
    pairing: Pairing = request.app.state.pairing
    return pairing


def get_episodes(request: Request) -> Episodes:
    episodes: Episodes = request.app.state.episodes
    return episodes


def get_signaling(request: Request) -> Signaling:
    signaling: Signaling = request.app.state.signaling
    return signaling


def get_guards(request: Request) -> Guards:
    guards: Guards = request.app.state.guards
    return guards


def get_history(request: Request) -> History:
    history: History = request.app.state.history
    return history


def get_metrics(request: Request) -> CoordMetrics:
    metrics: CoordMetrics = request.app.state.metrics
    return metrics


def get_completion(request: Request) -> Completion:
    completion: Completion = request.app.state.completion
    return completion


def get_worker_records(request: Request) -> WorkerRecords:
    records: WorkerRecords = request.app.state.worker_records
    return records


ConfigDep = Annotated[CoordConfig, Depends(get_config)]
CoordinatorDep = Annotated[Coordinator, Depends(get_coordinator)]
WorkersDep = Annotated[Workers, Depends(get_workers)]
PairingDep = Annotated[Pairing, Depends(get_pairing)]
EpisodesDep = Annotated[Episodes, Depends(get_episodes)]
SignalingDep = Annotated[Signaling, Depends(get_signaling)]
GuardsDep = Annotated[Guards, Depends(get_guards)]
MetricsDep = Annotated[CoordMetrics, Depends(get_metrics)]
HistoryDep = Annotated[History, Depends(get_history)]
CompletionDep = Annotated[Completion, Depends(get_completion)]
WorkerRecordsDep = Annotated[WorkerRecords, Depends(get_worker_records)]


# --- who is asking ---------------------------------------------------------------------------


def get_client(request: Request, guards: GuardsDep) -> str:
    """The client address key this request is counted under (coord/guard/clients.py)."""
    return guards.client(request)


ClientDep = Annotated[str, Depends(get_client)]


def token_of(credentials: HTTPAuthorizationCredentials | None) -> str | None:
    if credentials is None or not credentials.credentials or len(credentials.credentials) > 512:
        return None
    return credentials.credentials


async def worker_for(workers: Workers, token: str | None) -> Worker:
    worker, revoked = await workers.holder(token) if token else (None, False)
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


async def current_worker(workers: WorkersDep, credentials: Credentials) -> Worker:
    return await worker_for(workers, token_of(credentials))


WorkerDep = Annotated[Worker, Depends(current_worker)]


async def owned(coordinator: Coordinator, session_id: str, worker: Worker) -> Session:
    """The session if it is this worker's; 404 otherwise (others' ids are not confirmed)."""
    session = await coordinator.session(session_id)
    if session is None or session.worker_id != worker.id:
        raise ApiError(404, "not_found", "no such session")
    return session


async def owned_session(
    session_id: SessionId, coordinator: CoordinatorDep, worker: WorkerDep
) -> Session:
    return await owned(coordinator, session_id, worker)


OwnedSession = Annotated[Session, Depends(owned_session)]


async def require_admin(
    config: ConfigDep, credentials: Credentials, guards: GuardsDep, client: ClientDep
) -> None:
    """The admin token, with wrong guesses limited per address (429 past the limit)."""
    guards.check_admin(client)
    token = token_of(credentials)
    if token is None or not same(token, config.admin_token):
        guards.admin_failed(client)
        raise ApiError(401, "unauthorized", "the admin token is required")


async def phone_session(pairing: PairingDep, credentials: Credentials) -> Session:
    token = token_of(credentials)
    session = await pairing.session_of_phone(token) if token else None
    if session is None:
        raise ApiError(401, "unauthorized", "a valid phone token is required (from /api/pair)")
    return session


PhoneSession = Annotated[Session, Depends(phone_session)]
