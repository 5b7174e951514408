"""Per-task plans: generators of waypoints, each reading the live scene when it is pulled, so
later waypoints can depend on how the grasp actually went."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Protocol

import numpy as np
import numpy.typing as npt

from crowdteleop.control.scripted.waypoints import Waypoint, at, yaw_aligned, yaw_of
from crowdteleop.errors import ConfigError
from crowdteleop.sim.config import SimConfig
from crowdteleop.sim.types import Pose, RobotState


class ScriptedScene(Protocol):
    """What a scripted operator and its plans read of a scene: a `Simulation`, or a bot's
    `crowdteleop.client.bot.RemoteWorld`, fed by the server's privileged messages."""

    @property
    def config(self) -> SimConfig: ...

    @property
    def control_dt(self) -> float: ...

    def robot_state(self) -> RobotState: ...

    def object_poses(self) -> dict[str, Pose]: ...


Plan = Callable[[ScriptedScene], Iterator[Waypoint]]

HOVER_M = 0.10
DROP_NEAR_SIDE_M = 0.05


def _object_name(sim: ScriptedScene) -> str:
    return next(name for name in sim.object_poses() if "/" not in name and name != "table")


def _pick(
    sim: ScriptedScene, grasp_frame: str, axis_yaw: float, period: float, grasp_depth: float = 0.0
) -> Iterator[Waypoint]:
    """Hover over `grasp_frame`, descend with the fingers aligned, close, wait.

    Poses are read again after each waypoint: objects may still be settling after a reset.
    """
    start = sim.robot_state().end_effector
    rotation = yaw_aligned(start, axis_yaw, period)

    def above() -> npt.NDArray[np.float64]:
        return sim.object_poses()[grasp_frame].position + [0.0, 0.0, HOVER_M]

    yield Waypoint(at(above(), rotation), False, tolerance_m=0.02, label="hover")
    yield Waypoint(at(above(), rotation), False, tolerance_m=0.01, dwell_s=0.2, label="align")
    down = sim.object_poses()[grasp_frame].position + [0.0, 0.0, -grasp_depth]
    yield Waypoint(at(down, rotation), False, tolerance_m=0.006, dwell_s=0.1, label="descend")
    yield Waypoint(at(down, rotation), True, tolerance_m=0.02, dwell_s=0.5, label="grasp")


def lift(sim: ScriptedScene) -> Iterator[Waypoint]:
    name = _object_name(sim)
    cube = sim.object_poses()[name]
    yield from _pick(sim, name, yaw_of(cube), np.pi / 2)
    hand = sim.robot_state().end_effector
    yield Waypoint(at(hand.position + [0, 0, 0.15], hand.rotation), True, label="lift")


def pick_place(sim: ScriptedScene) -> Iterator[Waypoint]:
    name = _object_name(sim)
    home = sim.robot_state().end_effector.position
    yield from _pick(sim, name, 0.0, np.pi / 2, grasp_depth=0.01)
    hand = sim.robot_state().end_effector
    target = sim.object_poses()[f"{name}/target"].position.copy()
    # drop on the near side of the target, within the bin's quadrant: shorter arms (Panda)
    # cannot stretch to its centre with the can held high
    toward_home = home[:2] - target[:2]
    target[:2] += DROP_NEAR_SIDE_M * toward_home / max(float(np.linalg.norm(toward_home)), 1e-9)
    carry_z = target[2] + 0.30
    yield Waypoint(at([*hand.position[:2], carry_z], hand.rotation), True, 0.03, label="lift")
    yield Waypoint(at([*target[:2], carry_z], hand.rotation), True, 0.02, label="carry")
    yield Waypoint(at([*target[:2], target[2] + 0.17], hand.rotation), True, 0.02, label="lower")
    yield Waypoint(
        at([*target[:2], target[2] + 0.17], hand.rotation), False, 0.05, 0.4, label="drop"
    )
    yield Waypoint(at([*target[:2], carry_z], hand.rotation), False, 0.03, label="retreat")


def nut_assembly(sim: ScriptedScene) -> Iterator[Waypoint]:
    name = _object_name(sim)
    nut = sim.object_poses()[name]
    # The handle sticks out along the nut's x axis: close the fingers across it.
    yield from _pick(sim, f"{name}/handle", yaw_of(nut) + np.pi / 2, np.pi)
    hand = sim.robot_state().end_effector
    offset = sim.object_poses()[name].position - hand.position  # nut centre from the hand
    peg = sim.object_poses()[f"{name}/target"].position
    carry_z = peg[2] + 0.20 - offset[2]
    over_peg = peg[:2] - offset[:2]
    yield Waypoint(at([*hand.position[:2], carry_z], hand.rotation), True, 0.02, label="lift")
    yield Waypoint(at([*over_peg, carry_z], hand.rotation), True, 0.01, 0.3, label="carry")
    low_z = peg[2] + 0.02 - offset[2]
    yield Waypoint(at([*over_peg, low_z], hand.rotation), True, 0.015, label="lower")
    yield Waypoint(at([*over_peg, low_z], hand.rotation), False, 0.05, 0.3, label="release")
    yield Waypoint(at([*over_peg, carry_z], hand.rotation), False, 0.03, label="retreat")


PLANS: dict[str, Plan] = {
    "lift": lift,
    "mujoco-lift": lift,
    "pick-place-can": pick_place,
    "nut-assembly-round": nut_assembly,
}


def plan_for(task: str) -> Plan:
    try:
        return PLANS[task]
    except KeyError:
        raise ConfigError(
            f"no scripted operator for task {task!r}; available: {', '.join(PLANS)}"
        ) from None
