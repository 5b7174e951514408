"""The scripted bot (crowdteleop.client.bot), fed the server's messages without a network."""

from __future__ import annotations


def test_the_bot_presses_the_clutch_again_only_once_the_server_applied_its_release():
    """After a reset the server must see the bot let go before the next press: it applies
    only the latest pose of each step, and poses of the last episode may still be arriving
    (pressed). A press that follows the release too soon leaves the server anchored on a
    stale pose, and the bot steering an arm that is not where it thinks (it stalls)."""
    from crowdteleop.client.bot import Bot
    from crowdteleop.client.connection import TeleopClient
    from crowdteleop.sim import SimConfig, make_simulation
    from crowdteleop.teleop.protocol import Hello, PrivilegedState
    from crowdteleop.teleop.session import _privileged

    sim = make_simulation(SimConfig(task="lift"))
    try:
        sim.reset(0)
        scene = _privileged(sim, sim.robot_state().end_effector)
    finally:
        sim.close()
    client = TeleopClient("http://127.0.0.1:9", "worker-token", role="admin", admin_token="x")
    sent: list[dict] = []
    client.send_raw = lambda channel, message: sent.append(message) or True  # type: ignore[method-assign]
    client.state.hello = Hello(
        session_id="s", peer_id="p", role="admin", task="lift", instruction="", fps=20.0,
        width=320, height=240, controlling_device="bot",
    )  # fmt: skip
    Bot(client, seed=0)  # drives through client.on_privileged, as messages arrive

    def server_step(step: int, applied_seq: int) -> dict:
        client.on_privileged(PrivilegedState(step=step, scene=1, command_seq=applied_seq, **scene))
        return sent[-1]

    release = server_step(0, applied_seq=0)  # a new scene: let go
    assert release["engaged"] is False
    for step in (1, 2):  # the server still applies older (pressed) poses: keep letting go
        assert server_step(step, applied_seq=release["seq"] - 1)["engaged"] is False
    assert server_step(3, applied_seq=release["seq"])["engaged"] is True  # release applied
