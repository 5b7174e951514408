"""Every episode says which region recorded it and how far the worker was from each (issue 14,
item 4): a warm spare, built before anyone's region, records its assigned worker's."""

from __future__ import annotations

import asyncio

from crowdteleop.dataset.build import episode_files, read_inputs
from crowdteleop.recording.metadata import RegionChoice
from crowdteleop.teleop.assign import assigned_config
from crowdteleop.teleop.config import TeleopConfig
from crowdteleop.teleop.messages import Assignment
from crowdteleop.teleop.session import TeleopSession
from tests.teleop.test_practice import Worker


def test_a_spares_episodes_carry_the_region_of_the_worker_it_was_assigned(tmp_path):
    spare = TeleopConfig(recording={"directory": tmp_path / "spare"}, standby=True)
    choice = RegionChoice(region="china", rtts_ms={"oregon": 182.4, "china": 21.0})
    assignment = Assignment(
        session_id="s_1",
        worker_id="w_1",
        token="worker-token-1",
        admin_token="admin-token-1",
        recording_directory=tmp_path / "worker",
        region=choice,
    )

    async def scenario() -> None:
        session = await TeleopSession.create(spare)
        try:
            assert session.tracker.metadata.region is None
            session.assign(assigned_config(spare, assignment))
            await Worker(session).hold(5)  # the first move starts episode 1
            assert session.tracker.state == "running"
        finally:
            await session.close()  # stores it, as a disconnect

    asyncio.run(scenario())
    [(_path, episode)] = read_inputs(episode_files([tmp_path / "worker"]))[0]
    assert episode.outcome == "disconnect"
    assert episode.metadata["worker_id"] == "w_1"
    assert episode.metadata["region"] == {
        "region": "china",
        "rtts_ms": {"oregon": 182.4, "china": 21.0},
    }
