"""`crowdteleop bot`: a scripted operator driving a session through the network.

The bot is a client like a worker's browser: it sees what the server sends and commands the
arm with device poses. What a person gets from their eyes (where the cube is) the bot gets
from the admin-only channel, so it needs the admin token; workers never receive it.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from crowdteleop.client.connection import TeleopClient
from crowdteleop.control.config import MappingConfig
from crowdteleop.control.scripted.operator import OperatorStyle, ScriptedOperator
from crowdteleop.control.scripted.skills import style_for
from crowdteleop.sim.config import SimConfig
from crowdteleop.sim.types import Pose, RobotState
from crowdteleop.teleop.protocol import PrivilegedState
from crowdteleop.vocab import InjectedFault, SkillName

# Steps a finished plan waits for its episode to end before asking for a new scene: past the
# server's success hold (`TeleopConfig.success_hold_steps`, 10), since some tasks succeed only
# once the hand has let go (stack, pick-place) and need the hold after the plan's last move.
RESET_AFTER_STEPS = 20


def _pose(values: tuple[float, ...]) -> Pose:
    return Pose(np.array(values[:3]), np.array(values[3:7]))


class RemoteWorld:
    """The part of a `Simulation` a scripted operator reads, fed by privileged messages."""

    def __init__(self, task: str, control_hz: float) -> None:
        self.config = SimConfig(task=task, control_hz=control_hz)
        self.control_dt = 1.0 / control_hz
        self.latest: PrivilegedState | None = None

    def robot_state(self) -> RobotState:
        assert self.latest is not None, "no privileged state received yet"
        zeros = np.zeros(0)
        return RobotState(
            joint_positions=zeros,
            joint_velocities=zeros,
            end_effector=_pose(self.latest.end_effector),
            base=Pose(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])),
            gripper_closed_fraction=0.0,
        )

    def object_poses(self) -> dict[str, Pose]:
        assert self.latest is not None, "no privileged state received yet"
        return {name: _pose(values) for name, values in self.latest.objects.items()}


@dataclass
class BotResult:
    episodes: list[str] = field(default_factory=list)  # outcomes, in order
    seconds: float = 0.0

    @property
    def successes(self) -> int:
        return self.episodes.count("success")


class Bot:
    """Sends one command per server step, in step with the privileged stream.

    Commands go through `client`; the object poses come from `observer`'s admin channel, which
    is `client` itself unless a bot drives as a worker (or phone) and watches as an admin.

    A practice round (`crowdteleop.teleop.practice`) the bot skips, as a worker may: a scripted
    operator has nothing to learn, one message costs nothing, and the crowd's episode times
    then measure the task, not the round. Skipping rather than asking servers to turn the
    round off keeps bots on the very path a worker's page takes."""

    def __init__(
        self,
        client: TeleopClient,
        style: OperatorStyle | None = None,
        mapping: MappingConfig | None = None,
        seed: int = 0,
        observer: TeleopClient | None = None,
    ) -> None:
        self.client = client
        self.style = style
        self.mapping = mapping
        self.seed = seed
        self.operator: ScriptedOperator | None = None
        self.world: RemoteWorld | None = None
        self._scene: int | None = None
        self.episodes_wanted: int | None = None
        # (position, quaternion, engaged, gripper) as last sent by `TeleopClient.send_pose`
        self._last_pose: tuple[Iterable[float], Iterable[float], bool, bool] | None = None
        self._await_seq: int | None = None  # a pose the server must apply before we go on
        self._skipped_practice = False
        self._finished_at: int | None = None  # the step the plan finished at
        (observer or client).on_privileged = self._on_privileged

    def _on_privileged(self, message: PrivilegedState) -> None:
        hello = self.client.state.hello
        if hello is None:
            return
        if self.world is None:
            self.world = RemoteWorld(hello.task, hello.fps)
        self.world.latest = message
        if self.operator is None:
            self.operator = ScriptedOperator(
                self.world,
                mapping=self.mapping,
                style=self.style,
                seed=self.seed,
            )
        if (
            self.episodes_wanted is not None
            and len(self.client.state.episodes) >= self.episodes_wanted
        ):
            return  # done: leave the arm alone
        if self._practising():
            return  # the scene resets when the round ends: the operator starts then
        if message.scene != self._scene:  # the server reset the scene: start over
            self._scene = message.scene
            self.operator.reset()
            self._finished_at = None
            # Let go of the clutch until the server has applied that, so it re-anchors on our
            # next press. (Poses of the last episode still in flight may have pressed it again
            # after the reset; and the server applies only the latest pose of each step, so a
            # release followed at once by a press could go unseen, leaving the server anchored
            # elsewhere than we are.)
            origin = self.operator.style.device_origin
            self._last_pose = (origin, (0.0, 0.0, 0.0, 1.0), False, False)
            self._await_seq = self.client.send_pose(*self._last_pose)
            return
        if self.operator.finished:
            self._after_plan(message.step)
            return
        if self._await_seq is not None and message.command_seq < self._await_seq:
            # The server has not applied our clutch release or press yet. It anchors the device
            # to the arm on the first engaged pose it applies, so keep sending that very pose:
            # moving on now would offset the whole episode by a step of hand motion.
            assert self._last_pose is not None
            self.client.send_pose(*self._last_pose)
            return
        engaging = not self.operator.anchored  # the next command is the clutch press
        command = self.operator.command()
        self._last_pose = (
            command.position,
            command.quaternion,
            command.engaged,
            command.gripper_closed,
        )
        seq = self.client.send_pose(*self._last_pose)
        self._await_seq = seq if engaging else None
        if self.operator.finished:
            self._finished_at = message.step

    def _after_plan(self, step: int) -> None:
        """The plan is done: let a success hold; if the episode has not ended after
        `RESET_AFTER_STEPS`, ask for a new scene (once)."""
        if self._finished_at is not None and step - self._finished_at >= RESET_AFTER_STEPS:
            self._finished_at = None
            self.client.request("reset")

    def _practising(self) -> bool:
        """Whether a practice round runs (skipped once: the events channel is reliable)."""
        status = self.client.state.status
        if status is None or status.practice != "running":
            return False
        if not self._skipped_practice:
            self._skipped_practice = True
            self.client.request("skip_practice")
        return True

    async def stream(self, hz: float) -> None:
        """Also resend the latest pose `hz` times a second, unsynchronized with the server's
        steps, as a phone streams its pose: what control-to-photon latency is measured on."""
        while True:
            await asyncio.sleep(1.0 / hz)
            if self._last_pose is not None:
                self.client.send_pose(*self._last_pose)

    async def run(self, episodes: int, timeout_s: float) -> BotResult:
        """Drive until `episodes` episodes ended (any outcome) or `timeout_s` passed."""
        started = time.monotonic()
        self.episodes_wanted = episodes
        await self.client.wait_for(lambda state: len(state.episodes) >= episodes, timeout=timeout_s)
        return BotResult(
            [episode.outcome for episode in self.client.state.episodes[:episodes]],
            time.monotonic() - started,
        )


async def run_bot(
    url: str,
    token: str,
    admin_token: str,
    episodes: int = 1,
    timeout_s: float = 300.0,
    seed: int = 0,
    skill: SkillName | None = None,
    fault: InjectedFault | None = None,
) -> BotResult:
    """One bot driving the session at `url`; `skill` names its operator's style (None: the
    default operator), `fault` one it makes in every episode."""
    client = TeleopClient(url, token, role="admin", admin_token=admin_token, device="bot")
    bot = Bot(client, style=style_for(skill, fault), seed=seed)
    await client.connect()
    try:
        return await bot.run(episodes, timeout_s)
    finally:
        await client.close()


def main(
    url: str,
    token: str,
    admin_token: str,
    episodes: int,
    timeout_s: float,
    skill: SkillName | None = None,
    fault: InjectedFault | None = None,
) -> BotResult:
    return asyncio.run(
        run_bot(url, token, admin_token, episodes, timeout_s, skill=skill, fault=fault)
    )
