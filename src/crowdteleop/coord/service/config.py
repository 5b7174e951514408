"""Settings of one coordination server (the CLI builds them; tests pass them directly)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, cast

import yaml
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from crowdteleop.coord.fleet.ray_launcher import RayLauncherConfig
from crowdteleop.coord.fleet.turn import TurnConfig
from crowdteleop.coord.guard.clients import ProxyTrust
from crowdteleop.coord.guard.security import ADMIN_TOKEN_MIN_BITS, estimated_entropy_bits
from crowdteleop.coord.service.campaign import CampaignConfig, read_structured
from crowdteleop.recording.metadata import RegionName
from crowdteleop.teleop.messages import IceServer, IceTransportPolicy

if TYPE_CHECKING:
    from pydantic_settings import BaseSettings

# CROWDTELEOP_<FIELD> sets a CoordConfig field (`crowdteleop serve`, docs/coordination.md).
ENV_PREFIX = "CROWDTELEOP_"
MAX_SPARES_PER_KIND = 16
REVIEWER_NAME = re.compile(r"[A-Za-z0-9_.-]{1,64}")


class AdmissionConfig(BaseModel):
    """Who may join and queue, and how many: a join link is public (docs/security.md)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    joins_per_minute_per_address: int = Field(
        30,
        ge=1,
        description="joins from one address (/64 for IPv6) in any minute: a lab's NAT joins a "
        "class at once, a script joins hundreds",
    )
    joins_per_minute: int = Field(600, ge=1, description="joins from everyone in any minute")
    max_queue: int = Field(100, ge=0, description="queued sessions at most; more are refused")
    max_wait_s: float = Field(
        3600.0,
        gt=0,
        description="a new session whose estimated wait is longer is refused, and a queued one "
        "that has waited this long ends (reason queue_timeout)",
    )
    live_sessions_per_address: int = Field(
        8, ge=1, description="queued, starting or ready sessions from one address"
    )


class CoordConfig(BaseModel):
    """Everything the coordinator needs; `campaigns[0]` is the one a join link gets by default."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    database_url: str = "sqlite:///data/coord.sqlite3"
    data_dir: Path = Field(Path("data"), description="episodes, teleop configs and logs")
    campaigns: list[CampaignConfig] = Field(default_factory=lambda: [CampaignConfig()])
    capacity: int = Field(
        2, ge=1, le=256, description="teleop servers running at once (with `ray`: the cluster's)"
    )
    ray: RayLauncherConfig | None = Field(
        None, description="run teleop servers on this Ray cluster instead of as local processes"
    )
    spare_servers: int | Literal["auto"] = Field(
        "auto",
        description="warm teleop servers kept ready per (task, robot, controller), so a worker "
        "sees the robot in about a second instead of waiting for a simulation to build; on a "
        "cluster for all replicas together, with local processes per replica. 'auto': every "
        "free slot kept warm (a burst of workers gets robots at once), as many as the machine's "
        "available memory holds (each server's measured), started in parallel; on a cluster, "
        "where a spare holds a slot, one per kind",
    )
    admin_token: str = Field(min_length=16, max_length=256)
    reviewer_tokens: dict[str, str] = Field(
        default_factory=dict,
        description="reviewer name -> token for the /review page (docs/review.md): each "
        "decision records the name; the admin token reviews too, as 'admin'",
    )
    public_url: str = Field(
        "http://127.0.0.1:8000", description="base URL phones and browsers reach us at"
    )
    teleop_host: str = Field(
        "127.0.0.1",
        description="the address launched teleop servers listen on for signalling and the "
        "admin door: loopback unless bots or proxies elsewhere must reach them",
    )
    internal_url: str | None = Field(
        None, description="base URL teleop servers report to; default: public_url"
    )
    ice_servers: list[IceServer] = Field(
        default_factory=list, description="STUN/TURN servers for everyone (URLs or objects)"
    )
    turn: TurnConfig | None = Field(
        None, description="a TURN server taking REST API credentials: one set per session"
    )
    ice_transport_policy: IceTransportPolicy = Field(
        "all",
        description="what the pages may connect by: 'relay' allows TURN only (hides the "
        "workers' and servers' addresses from each other)",
    )
    heartbeat_timeout_s: float = Field(30.0, gt=0, description="silent this long: abandoned")
    reaper_interval_s: float = Field(1.0, gt=0)
    replica_name: str | None = Field(
        None,
        max_length=128,
        description="this coordinator's name among replicas sharing the database "
        "(default host:port: a restarted one takes its sessions back at once)",
    )
    replica_stale_after_s: float = Field(
        10.0, gt=0, description="a replica silent this long is gone: others take its sessions"
    )
    region: RegionName | None = Field(
        None,
        description="this coordinator's name in its campaigns' `regions` (needed when one "
        "lists regions): recorded with every episode of its workers",
    )
    teleop_start_timeout_s: float = Field(120.0, gt=0)
    pairing_ttl_s: float = Field(120.0, gt=0)
    pair_failures_per_minute: int = Field(
        10, ge=1, description="wrong pairing codes per client address (/64 for IPv6)"
    )
    pair_failures_per_minute_total: int = Field(
        300,
        ge=1,
        description="wrong pairing codes from everyone together (the code space's budget)",
    )
    admin_failures_per_minute: int = Field(
        10, ge=1, description="wrong admin tokens per client address before 429"
    )
    admission: AdmissionConfig = Field(default_factory=lambda: AdmissionConfig())
    trusted_proxies: list[str] = Field(
        default_factory=list,
        description="addresses or networks (CIDR) of reverse proxies whose X-Forwarded-For is "
        "believed; none by default, so a client cannot choose the address it is counted under",
    )
    health_interval_s: float = Field(1.0, gt=0, description="how often each server is probed")
    health_timeout_s: float = Field(2.0, gt=0, description="one probe's answer must come by then")
    unresponsive_after_s: float = Field(
        6.0, gt=0, description="a server with no good probe for this long is ended as hung"
    )
    max_restarts: int = Field(
        2, ge=0, le=10, description="new servers a session gets after its server crashed or hung"
    )
    max_body_bytes: int = Field(256 * 1024, ge=1024)
    body_timeout_s: float = Field(
        10.0, gt=0, description="a request body must arrive whole within this (408 after)"
    )
    header_timeout_s: float = Field(
        10.0, gt=0, description="a new connection must send its request's headers within this"
    )
    max_connections: int = Field(
        1000, ge=1, description="connections served at once; more get 503 (uvicorn's limit)"
    )
    api_docs: bool = Field(
        False,
        description="serve the API's schema and docs (/openapi.json, /docs, /redoc): a map of "
        "every endpoint, so off unless you are developing against it",
    )
    teleop: dict[str, Any] = Field(
        default_factory=dict,
        description="TeleopConfig fields every session gets (video, limits, ...)",
    )

    @field_validator("admin_token")
    @classmethod
    def _strong_admin_token(cls, token: str) -> str:
        bits = estimated_entropy_bits(token)
        if bits < ADMIN_TOKEN_MIN_BITS:
            raise ValueError(
                f"the admin token looks too weak (~{bits:.0f} bits; at least "
                f"{ADMIN_TOKEN_MIN_BITS} needed): leave it out to get a random one, or use "
                "e.g. `python -c 'import secrets; print(secrets.token_urlsafe(32))'`"
            )
        return token

    @field_validator("reviewer_tokens")
    @classmethod
    def _reviewers(cls, reviewers: dict[str, str]) -> dict[str, str]:
        for name, token in reviewers.items():
            if not REVIEWER_NAME.fullmatch(name) or name in ("admin", "auto"):
                raise ValueError(f"reviewer name {name!r}: 1-64 of A-Z a-z 0-9 _ . -, not admin")
            if estimated_entropy_bits(token) < ADMIN_TOKEN_MIN_BITS:
                raise ValueError(
                    f"reviewer {name}'s token looks too weak: as strong as the admin token's "
                    "(e.g. `python -c 'import secrets; print(secrets.token_urlsafe(32))'`)"
                )
        if len(set(reviewers.values())) != len(reviewers):
            raise ValueError("each reviewer needs a token of their own")
        return reviewers

    @field_validator("spare_servers")
    @classmethod
    def _spares_bounded(cls, spares: int | str) -> int | str:
        if isinstance(spares, int) and not 0 <= spares <= MAX_SPARES_PER_KIND:
            raise ValueError(f"spare_servers: 'auto' or 0 to {MAX_SPARES_PER_KIND} per kind")
        return spares

    @field_validator("trusted_proxies")
    @classmethod
    def _networks(cls, entries: list[str]) -> list[str]:
        ProxyTrust.of(entries)  # raises ValueError on a malformed entry
        return entries

    @model_validator(mode="after")
    def _unique_campaigns(self) -> CoordConfig:
        names = [c.name for c in self.campaigns]
        if not names or len(set(names)) != len(names):
            raise ValueError(f"need at least one campaign, with unique names, got {names}")
        return self

    @model_validator(mode="after")
    def _region_listed(self) -> CoordConfig:
        for campaign in self.campaigns:
            names = [region.name for region in campaign.regions]
            if names and self.region not in names:
                raise ValueError(
                    f"campaign {campaign.name!r} lists regions {names}: set `region` to this "
                    f"coordinator's name among them (it is {self.region!r})"
                )
        return self

    def region_origins(self) -> list[str]:
        """Every region's origin: the pages may fetch their /api/ping (CSP connect-src)."""
        origins = {region.origin for c in self.campaigns for region in c.regions}
        return sorted(origins)

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


def file_settings(path: Path) -> dict[str, Any]:
    """The CoordConfig fields a JSON or YAML file sets, as written: they are validated once,
    with the other layers (`crowdteleop serve`), so a field may come from anywhere."""
    try:
        data = read_structured(path) or {}
    except (ValueError, yaml.YAMLError) as exc:  # JSONDecodeError is a ValueError
        raise ValueError(f"{path} is not valid JSON or YAML: {exc}") from exc
    if not isinstance(data, dict):
        raise ValueError(f"{path}: a mapping of CoordConfig fields expected, got {data!r:.60}")
    return data


def environment_settings() -> dict[str, Any]:
    """The CoordConfig fields set as `CROWDTELEOP_<FIELD>` variables (any case; an empty one
    counts as unset), models, lists and dicts as JSON.

    pydantic-settings' source does the reading and the JSON decoding as for a BaseSettings;
    it needs only the model's fields, so CoordConfig stays a plain model that tests build."""
    from pydantic_settings import EnvSettingsSource

    source = EnvSettingsSource(
        cast("type[BaseSettings]", CoordConfig),
        case_sensitive=False,
        env_prefix=ENV_PREFIX,
        env_ignore_empty=True,
    )
    return source()
