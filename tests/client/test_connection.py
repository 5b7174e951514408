"""A Python client of the teleop server notices when its connection is gone (issue 29: a bot
whose connection failed mid-campaign waited 40 minutes for episodes that could never come)."""

from __future__ import annotations

import signal

import pytest

from crowdteleop.client.connection import ConnectionLostError, TeleopClient
from tests.fixtures.teleop_process import TOKEN, run, teleop_server


def test_a_connection_the_server_closes_is_reported_lost_not_waited_out(tmp_path):
    """The teleop server stops (SIGINT: it finishes and closes its peers) while a client waits
    on it: the wait ends with ConnectionLostError, not a timeout two minutes on."""
    with teleop_server(tmp_path) as server:

        async def scenario() -> None:
            client = TeleopClient(server.url, TOKEN)
            await client.connect()
            try:
                assert not client.lost
                server.process.send_signal(signal.SIGINT)
                with pytest.raises(ConnectionLostError, match=r"is (closed|failed)"):
                    await client.wait_for(lambda state: False, timeout=120)
                assert client.lost
            finally:
                await client.close()

        run(scenario())
