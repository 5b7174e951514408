"""The coordinator's worker API as a worker's pages call it: join, session, heartbeat, offer,
phone pairing. The bodies are the coordinator's own models (`coord.api.schemas`)."""

from __future__ import annotations

import asyncio
import contextlib
import json
from typing import Any, TypeVar
from urllib.parse import parse_qs, urlsplit

import aiohttp
from pydantic import BaseModel

from crowdteleop.coord.api.schemas import (
    JoinRequest,
    JoinResponse,
    OfferBody,
    PairingView,
    PairRequest,
    PairResponse,
    SessionView,
    TeleopAccess,
)
from crowdteleop.teleop.messages import OfferAnswer

Model = TypeVar("Model", bound=BaseModel)
HEARTBEAT_S = 2.0
GATEWAY_ERRORS = (502, 503, 504)  # a reverse proxy whose coordinator is away (restarting)
RECONNECT_S = 60.0  # as teleop.js: well inside the coordinator's 30 s heartbeat timeout


class CoordinatorRefusedError(ConnectionError):
    """The coordinator answered with an error body (`ErrorBody`): its code and message."""

    def __init__(self, status: int, code: str, message: str) -> None:
        super().__init__(f"{status} {code}: {message}")
        self.status, self.code = status, code


class CoordinatorUnreachableError(ConnectionError):
    """A reverse proxy answered for the coordinator: it is away (restarting)."""


def _error_body(payload: Any) -> bool:
    """Whether `payload` is the coordinator's own `ErrorBody`, not a proxy's page."""
    return isinstance(payload, dict) and "error" in payload


class WorkerApi:
    """One worker's calls: a join link's parameters in, a bearer token kept."""

    def __init__(self, http: aiohttp.ClientSession, base_url: str, campaign: str | None) -> None:
        self.http, self.base_url, self.campaign = http, base_url.rstrip("/"), campaign
        self.token = ""
        self.view: SessionView | None = None
        self._beating: asyncio.Task[None] | None = None

    async def _call(
        self,
        method: str,
        path: str,
        reply: type[Model],
        body: BaseModel | None = None,
        token: str | None = None,
    ) -> Model:
        """One call; while the coordinator cannot be reached (restarting: no connection, or
        its reverse proxy's 502/503/504), retried for up to RECONNECT_S, as the page keeps
        heart-beating through an outage."""
        deadline = asyncio.get_running_loop().time() + RECONNECT_S
        while True:
            try:
                return await self._call_once(method, path, reply, body, token)
            except (aiohttp.ClientConnectionError, CoordinatorUnreachableError):
                if not self.token or asyncio.get_running_loop().time() > deadline:
                    raise  # never joined: nothing to come back to
                await asyncio.sleep(1.0)

    async def _call_once(
        self,
        method: str,
        path: str,
        reply: type[Model],
        body: BaseModel | None,
        token: str | None,
    ) -> Model:
        bearer = self.token if token is None else token  # "": no credentials, as a phone
        headers = {"Authorization": f"Bearer {bearer}"} if bearer else {}
        if body is not None:
            headers["Content-Type"] = "application/json"
        data = body.model_dump_json(exclude_none=True) if body is not None else None
        async with self.http.request(
            method, f"{self.base_url}{path}", data=data, headers=headers
        ) as response:
            text = await response.text()
            try:
                payload: Any = json.loads(text)
            except ValueError:
                payload = None
            if response.status in GATEWAY_ERRORS and not _error_body(payload):
                # The proxy answered for a coordinator that is away (its own 503s say why).
                raise CoordinatorUnreachableError(f"{path}: {response.status} {text[:100]}")
            if response.status != 200:
                error = payload if isinstance(payload, dict) else {}
                raise CoordinatorRefusedError(
                    response.status, str(error.get("error", "?")), str(error.get("message", ""))
                )
        return reply.model_validate(payload)

    async def join(self, params: dict[str, str]) -> JoinResponse:
        joined = await self._call(
            "POST", "/api/join", JoinResponse, JoinRequest(params=params, campaign=self.campaign)
        )
        self.token = joined.worker_token
        return joined

    async def start_session(self) -> SessionView:
        self.view = await self._call("POST", "/api/sessions", SessionView)
        self._beating = asyncio.create_task(self._beat(), name=f"heartbeat-{self.session_id}")
        return self.view

    @property
    def session_id(self) -> str:
        assert self.view is not None, "no session yet: call start_session()"
        return self.view.session_id

    async def _beat(self) -> None:
        while True:
            await asyncio.sleep(HEARTBEAT_S)
            with contextlib.suppress(aiohttp.ClientError, CoordinatorRefusedError):
                path = f"/api/sessions/{self.session_id}/heartbeat"
                self.view = await self._call("POST", path, SessionView)

    async def until_ready(self, timeout_s: float) -> SessionView:
        """Wait in the queue as the page does; the session's view once it is ready."""
        deadline = asyncio.get_running_loop().time() + timeout_s
        while True:
            await self.refresh()
            assert self.view is not None
            if self.view.state == "ready":
                return self.view
            if self.view.state == "ended":
                raise CoordinatorRefusedError(409, "ended", f"ended: {self.view.ended_reason}")
            if asyncio.get_running_loop().time() > deadline:
                raise TimeoutError(f"not ready after {timeout_s:.0f} s ({self.view.state})")
            await asyncio.sleep(0.25)

    async def refresh(self) -> SessionView:
        self.view = await self._call("GET", f"/api/sessions/{self.session_id}", SessionView)
        return self.view

    async def offer(self, sdp: str) -> OfferAnswer:
        path = f"/api/sessions/{self.session_id}/offer"
        return await self._call("POST", path, OfferAnswer, OfferBody(sdp=sdp, type="offer"))

    async def pair_phone(self) -> str:
        """A phone token, as a phone scanning the page's QR code gets one."""
        pairing = await self._call("POST", f"/api/sessions/{self.session_id}/pairing", PairingView)
        key = parse_qs(urlsplit(pairing.phone_url).query).get("key", [None])[0]
        paired = await self._call(
            "POST", "/api/pair", PairResponse, PairRequest(code=pairing.code, key=key), token=""
        )
        return paired.phone_token

    async def phone_offer(self, phone_token: str, sdp: str) -> OfferAnswer:
        body = OfferBody(sdp=sdp, type="offer")
        return await self._call("POST", "/api/phone/offer", OfferAnswer, body, token=phone_token)

    async def teleop_access(self, admin_token: str) -> TeleopAccess:
        """The session's teleop server and tokens: how a bot reads object poses (admin only)."""
        path = f"/api/admin/sessions/{self.session_id}/teleop"
        return await self._call("GET", path, TeleopAccess, token=admin_token)

    async def leave(self) -> None:
        if self._beating is not None:
            self._beating.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._beating
        if self.view is not None:
            with contextlib.suppress(aiohttp.ClientError, CoordinatorRefusedError):
                await self._call("POST", f"/api/sessions/{self.session_id}/leave", SessionView)
