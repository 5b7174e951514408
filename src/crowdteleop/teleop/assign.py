"""Warm spares: a teleop server started before its worker arrives, then given its session.

Building a simulation takes seconds (robosuite model, fast renderer, IK model); a worker who
clicks start should see the robot at once. So the coordinator keeps spare servers running,
each with its task, robot and controller but a placeholder identity, and hands one to a session
with `POST /assign`: new ids, new tokens, where to record and whom to report to.
"""

from __future__ import annotations

from crowdteleop.teleop.config import TeleopConfig
from crowdteleop.teleop.messages import Assignment


def assigned_config(config: TeleopConfig, assignment: Assignment) -> TeleopConfig:
    """`config` with the session's identity and its campaign's practice round: everything else
    (the simulation) stays."""
    recording = config.recording.model_copy(update={"directory": assignment.recording_directory})
    return TeleopConfig.model_validate(
        {
            **config.model_dump(),
            "session_id": assignment.session_id,
            "worker_id": assignment.worker_id,
            "token": assignment.token,
            "admin_token": assignment.admin_token,
            "recording": recording.model_dump(),
            "report_url": assignment.report_url,
            "report_token": assignment.report_token,
            "ice_servers": [s.model_dump() for s in assignment.ice_servers],
            "practice_s": assignment.practice_s,  # the campaign's, not the spare's
            "region": assignment.region.model_dump() if assignment.region else None,
            "standby": False,
        }
    )
