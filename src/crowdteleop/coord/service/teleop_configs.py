"""The `TeleopConfig` each teleop server is started with: a session's, or a warm spare's."""

from __future__ import annotations

import time
from typing import Any

from crowdteleop.coord.db.spare_registry import SpareKey
from crowdteleop.coord.db.tables import Session
from crowdteleop.coord.fleet.turn import turn_credentials
from crowdteleop.coord.guard.session_keys import SessionKeys
from crowdteleop.coord.service.config import CoordConfig
from crowdteleop.teleop.config import TeleopConfig
from crowdteleop.teleop.messages import Assignment, IceServer


def deep_merge(base: dict[str, Any], extra: dict[str, Any]) -> dict[str, Any]:
    merged = dict(base)
    for key, value in extra.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = deep_merge(merged[key], value)
        else:
            merged[key] = value
    return merged


def assignment_of(config: TeleopConfig) -> Assignment:
    """What a warm spare needs to become the server of the session `config` describes."""
    assert config.admin_token is not None  # the coordinator always gives one
    return Assignment(
        session_id=config.session_id,
        worker_id=config.worker_id,
        token=config.token,
        admin_token=config.admin_token,
        recording_directory=config.recording.directory,
        report_url=config.report_url,
        report_token=config.report_token,
        ice_servers=list(config.ice_servers),
        practice_s=config.practice_s,
        region=config.region,
    )


class TeleopConfigs:
    """Builds teleop server configs from the coordinator's settings and secret."""

    def __init__(self, config: CoordConfig, keys: SessionKeys) -> None:
        self.config, self.keys = config, keys

    def ice_servers(self, name: str) -> list[IceServer]:
        """Everyone's STUN/TURN servers, and TURN credentials of `name`'s own (a session's,
        a page's, a teleop server's), fresh now."""
        servers = list(self.config.ice_servers)
        if self.config.turn is not None:
            servers.append(turn_credentials(self.config.turn, name, time.time()))
        return servers

    def ice_servers_dump(self, name: str) -> list[dict[str, Any]]:
        return [server.model_dump() for server in self.ice_servers(name)]

    def for_session(self, session: Session, report_token: str) -> TeleopConfig:
        directory = (self.config.data_dir / "episodes" / session.campaign / session.id).resolve()
        fields = deep_merge(
            self.config.teleop,
            {
                "session_id": session.id,
                "worker_id": session.worker_id,
                "token": self.keys.teleop_token(session.id),
                "admin_token": self.keys.teleop_admin_token(session.id),
                "sim": {"task": session.task, "robot": session.robot},
                "control": {"controller": session.controller},
                "recording": {"directory": str(directory)},
                "ice_servers": self.ice_servers_dump(session.id),
                "allowed_origins": [self.config.public_url],
                "report_url": f"{self.config.report_base_url}/internal/episodes",
                "report_token": report_token,
                "practice_s": self._practice_s(session.campaign),
                "region": session.region,
            },
        )
        return TeleopConfig.model_validate(fields)

    def _practice_s(self, campaign: str) -> float:
        """The session's campaign's practice round (a campaign since removed: none)."""
        found = self.config.campaign(campaign)
        return found.practice_s if found is not None else 0.0

    def spare_keys(self) -> list[SpareKey]:
        """The (task, robot, controller) combinations the campaigns hand out, round-robin."""
        keys: list[SpareKey] = []
        for campaign in self.config.campaigns:
            tasks, robots, controllers = campaign.tasks, campaign.robots, campaign.controllers
            for n in range(max(len(tasks), len(robots), len(controllers))):
                key = (
                    tasks[n % len(tasks)],
                    robots[n % len(robots)],
                    controllers[n % len(controllers)],
                )
                if key not in keys:
                    keys.append(key)
        return keys

    def for_spare(self, key: SpareKey, spare_id: str) -> TeleopConfig:
        """A spare's config: the simulation of `key`, a placeholder identity (standby). Its
        tokens are derived from the spare's id, so any replica can assign it."""
        task, robot, controller = key
        fields = deep_merge(
            self.config.teleop,
            {
                "session_id": spare_id,
                "worker_id": "unassigned",
                "token": self.keys.teleop_token(spare_id),
                "admin_token": self.keys.teleop_admin_token(spare_id),
                "standby": True,
                "sim": {"task": task, "robot": robot},
                "control": {"controller": controller},
                "recording": {
                    "directory": str((self.config.data_dir / "spares" / spare_id).resolve())
                },
                "ice_servers": self.ice_servers_dump(spare_id),
                "allowed_origins": [self.config.public_url],
            },
        )
        return TeleopConfig.model_validate(fields)
