"""A teleop server that cannot reach the coordinator at its report address (a Ray node given
the coordinator's loopback, issue 30) says so before the first demonstration: in its log, to
the worker's page, and in `/health`, which the coordinator's probes sum into `/metrics`. The
demonstrations are still stored; their reports wait (tests/teleop/test_report_outbox.py; the
coordinator's side: tests/coord/test_deploy_guide.py)."""

from __future__ import annotations

from crowdteleop.client.bot import Bot
from crowdteleop.client.connection import TeleopClient
from tests.fixtures.s3 import free_port
from tests.fixtures.teleop_process import ADMIN_TOKEN, TOKEN, run, teleop_server


def test_a_server_that_cannot_report_tells_the_worker_and_keeps_the_reports(tmp_path):
    nobody = f"http://127.0.0.1:{free_port()}/internal/episodes"
    with teleop_server(tmp_path, report_url=nobody, report_token="r" * 32) as server:

        async def one_demonstration() -> tuple[TeleopClient, dict, dict]:
            client = TeleopClient(server.url, TOKEN, role="worker")
            observer = TeleopClient(  # privileged state, which the scripted bot plans from
                server.url, TOKEN, role="admin", admin_token=ADMIN_TOKEN, video=False
            )
            Bot(client, seed=3, observer=observer)
            await client.connect()
            await observer.connect()
            await client.wait_for(lambda s: any(e.code == "reports_delayed" for e in s.errors), 30)
            before = await server.health()
            await client.wait_for(lambda s: any(e.outcome == "success" for e in s.episodes), 60)
            await client.wait_for(lambda s: bool(s.saved), 30)
            after = await server.health()
            await observer.close()
            await client.close()
            return client, before, after

        client, before, after = run(one_demonstration())
        log = server.log()
    told = next(e for e in client.state.errors if e.code == "reports_delayed")
    assert "saved" in told.message and "will count" in told.message, told.message
    assert before["reports_unreachable"] and before["reports_pending"] == 0
    assert after["reports_pending"] >= 1, "the stored demonstration's report waits"
    assert "cannot reach the coordinator at " + nobody in log and "internal_url" in log
    assert sorted((server.record_dir / "success").glob("*.hdf5")), "the demonstration is stored"
