"""STUN and TURN servers as WebRTC's `RTCIceServer` describes them: URLs, and for TURN the
username and credential. One model from the coordinator's settings through the teleop server's
config to the pages (`SessionView.ice_servers`) and the Python client; a bare URL string is
read as a server without credentials, so configs written before still load."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

IceTransportPolicy = Literal["all", "relay"]  # WebRTC's RTCIceTransportPolicy


class IceServer(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    urls: list[str] = Field(min_length=1, description="stun:, turn: or turns: URLs")
    username: str | None = Field(None, max_length=512)
    credential: str | None = Field(None, max_length=512)

    @model_validator(mode="before")
    @classmethod
    def _from_url(cls, data: Any) -> Any:
        if isinstance(data, str):
            return {"urls": [data]}
        if isinstance(data, dict) and isinstance(data.get("urls"), str):
            return {**data, "urls": [data["urls"]]}
        return data

    @model_validator(mode="after")
    def _known_schemes(self) -> IceServer:
        for url in self.urls:
            if not url.startswith(("stun:", "turn:", "turns:")):
                raise ValueError(
                    f"an ICE server URL starts with stun:, turn: or turns:, got {url!r}"
                )
        return self
