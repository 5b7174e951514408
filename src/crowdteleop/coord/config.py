"""Settings of one coordination server (the CLI builds them; tests pass them directly)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, model_validator

from crowdteleop.coord.campaign import CampaignConfig, read_structured


class CoordConfig(BaseModel):
    """Everything the coordinator needs; `campaigns[0]` is the one a join link gets by default."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    database_url: str = "sqlite:///data/coord.sqlite3"
    data_dir: Path = Field(Path("data"), description="episodes, teleop configs and logs")
    campaigns: list[CampaignConfig] = Field(default_factory=lambda: [CampaignConfig()])
    capacity: int = Field(2, ge=1, le=256, description="teleop servers running at once")
    spare_servers: int = Field(
        1,
        ge=0,
        le=16,
        description="warm teleop servers kept ready per (task, robot, controller), so a worker "
        "sees the robot in about a second instead of waiting for a simulation to build",
    )
    admin_token: str = Field(min_length=16, max_length=256)
    public_url: str = Field(
        "http://127.0.0.1:8000", description="base URL phones and browsers reach us at"
    )
    internal_url: str | None = Field(
        None, description="base URL teleop servers report to; default: public_url"
    )
    ice_servers: list[str] = Field(default_factory=list, description="STUN/TURN URLs")
    heartbeat_timeout_s: float = Field(30.0, gt=0, description="silent this long: abandoned")
    reaper_interval_s: float = Field(1.0, gt=0)
    teleop_start_timeout_s: float = Field(120.0, gt=0)
    pairing_ttl_s: float = Field(120.0, gt=0)
    pair_failures_per_minute: int = Field(10, ge=1, description="wrong codes per client IP")
    max_body_bytes: int = Field(256 * 1024, ge=1024)
    api_docs: bool = Field(
        False,
        description="serve the API's schema and docs (/openapi.json, /docs, /redoc): a map of "
        "every endpoint, so off unless you are developing against it",
    )
    teleop: dict[str, Any] = Field(
        default_factory=dict,
        description="TeleopConfig fields every session gets (video, limits, ...)",
    )

    @model_validator(mode="after")
    def _unique_campaigns(self) -> CoordConfig:
        names = [c.name for c in self.campaigns]
        if not names or len(set(names)) != len(names):
            raise ValueError(f"need at least one campaign, with unique names, got {names}")
        return self

    @property
    def default_campaign(self) -> CampaignConfig:
        return self.campaigns[0]

    def campaign(self, name: str | None) -> CampaignConfig | None:
        if name is None:
            return self.default_campaign
        return next((c for c in self.campaigns if c.name == name), None)

    @property
    def report_base_url(self) -> str:
        return (self.internal_url or self.public_url).rstrip("/")

    @classmethod
    def from_file(cls, path: Path, **overrides: Any) -> CoordConfig:
        data = read_structured(path) or {}
        return cls.model_validate({**data, **overrides})
