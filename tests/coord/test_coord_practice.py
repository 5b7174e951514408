"""The practice round is a campaign's setting: it reaches a session's teleop server whether
the coordinator launches one or hands over a warm spare (built before anyone's campaign)."""

from __future__ import annotations

from crowdteleop.coord.db.tables import Session
from crowdteleop.coord.guard.session_keys import SessionKeys
from crowdteleop.coord.service.config import CoordConfig
from crowdteleop.coord.service.teleop_configs import TeleopConfigs, assignment_of
from crowdteleop.teleop.assign import assigned_config
from tests.fixtures.coord import ADMIN


def _session(campaign: str) -> Session:
    return Session(
        id=f"session-{campaign}",
        worker_id="worker-1",
        campaign=campaign,
        task="lift",
        robot="Panda",
        controller="ik-velocity",
    )


def test_a_campaigns_practice_round_reaches_launched_servers_and_warm_spares(tmp_path):
    config = CoordConfig(
        admin_token=ADMIN,
        data_dir=tmp_path,
        campaigns=[{"name": "study"}, {"name": "quick", "practice_s": 0}],
    )
    configs = TeleopConfigs(config, SessionKeys(b"k" * 32))
    study = configs.for_session(_session("study"), report_token="report-token-1")
    quick = configs.for_session(_session("quick"), report_token="report-token-2")
    assert (study.practice_s, quick.practice_s) == (20.0, 0.0), "on by default, 0 turns it off"

    spare = configs.for_spare(("lift", "Panda", "ik-velocity"), "spare-1")
    assert spare.practice_s == 0.0, "a spare has no campaign yet"
    assert assigned_config(spare, assignment_of(study)).practice_s == 20.0
    assert assigned_config(spare, assignment_of(quick)).practice_s == 0.0
