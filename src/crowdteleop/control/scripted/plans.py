"""Per-task plans: generators of waypoints, each reading the live scene when it is pulled, so
later waypoints can depend on how the grasp actually went."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

from crowdteleop.control.scripted.waypoints import Waypoint, at, yaw_aligned, yaw_of
from crowdteleop.errors import ConfigError
from crowdteleop.sim.config import SimConfig
from crowdteleop.sim.types import Pose, RobotState
from crowdteleop.tasks import get_task, resolve


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
DESCEND = "descend"  # the label of the leg down to a grasp (an injected press happens there)
DROP_NEAR_SIDE_M = 0.05
DESCENT_STALL_S = 0.3  # held up this long over a pick-place object: grasp there


def _object_name(sim: ScriptedScene) -> str:
    return next(name for name in sim.object_poses() if "/" not in name and name != "table")


def _pick(
    sim: ScriptedScene,
    grasp_frame: str,
    axis_yaw: float,
    period: float,
    grasp_depth: float = 0.0,
    stall_s: float | None = None,
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
    yield Waypoint(
        at(down, rotation), False, tolerance_m=0.006, dwell_s=0.1, label=DESCEND, stall_s=stall_s
    )
    yield Waypoint(at(down, rotation), True, tolerance_m=0.02, dwell_s=0.5, label="grasp")


def lift(sim: ScriptedScene) -> Iterator[Waypoint]:
    name = _object_name(sim)
    cube = sim.object_poses()[name]
    yield from _pick(sim, name, yaw_of(cube), np.pi / 2)
    hand = sim.robot_state().end_effector
    yield Waypoint(at(hand.position + [0, 0, 0.15], hand.rotation), True, label="lift")


@dataclass(frozen=True)
class Grasp:
    """How to take an object: the fingers close along its `axis` (radians from its x axis;
    None: world x, for round objects), which repeats every `period`, `depth` below its origin
    (negative: above, so the palm clears a tall object's top)."""

    depth: float = 0.0
    axis: float | None = 0.0
    period: float = np.pi / 2


# Extents measured from robosuite's collision meshes (half sizes, m): milk 0.02 x 0.02 x
# 0.06-0.083, bread 0.024 x 0.02 x 0.024, cereal 0.05 x 0.015 x 0.075 (only its 3 cm side fits).
PICK_PLACE_GRASPS = {
    "Can": Grasp(depth=0.01, axis=None),
    "Milk": Grasp(depth=-0.05),
    "Bread": Grasp(),
    "Cereal": Grasp(depth=-0.04, axis=np.pi / 2, period=np.pi),
}


def pick_place(sim: ScriptedScene) -> Iterator[Waypoint]:
    name = _object_name(sim)
    home = sim.robot_state().end_effector
    grasp = PICK_PLACE_GRASPS[name]
    axis = 0.0 if grasp.axis is None else yaw_of(sim.object_poses()[name]) + grasp.axis
    # the fingers meet the bin's floor 0-15 mm short of the mark: without stall_s every
    # demonstration waited out the descent's timeout (~110 steps of an open hand at the can)
    yield from _pick(sim, name, axis, grasp.period, grasp.depth, stall_s=DESCENT_STALL_S)
    hand = sim.robot_state().end_effector
    target = sim.object_poses()[f"{name}/target"].position.copy()
    # drop on the near side of the target, within the bin's quadrant: shorter arms (Panda)
    # cannot stretch to its centre with the can held high
    toward_home = home.position[:2] - target[:2]
    target[:2] += DROP_NEAR_SIDE_M * toward_home / max(float(np.linalg.norm(toward_home)), 1e-9)
    carry_z = target[2] + 0.30
    # carry with the hand turned back as it started: a wrist turned far to grasp (a cereal box
    # across its thin side) cannot reach the far bins
    upright = home.rotation
    yield Waypoint(at([*hand.position[:2], carry_z], hand.rotation), True, 0.03, label="lift")
    yield Waypoint(at([*target[:2], carry_z], upright), True, 0.02, label="carry")
    yield Waypoint(at([*target[:2], target[2] + 0.17], upright), True, 0.02, label="lower")
    yield Waypoint(at([*target[:2], target[2] + 0.17], upright), False, 0.05, 0.4, label="drop")
    yield Waypoint(at([*target[:2], carry_z], upright), False, 0.03, label="retreat")


# How often a nut's hole repeats as it turns about its peg (None: round, any turn fits).
NUT_SYMMETRY = {"RoundNut": None, "SquareNut": np.pi / 2}


def nut_assembly(sim: ScriptedScene) -> Iterator[Waypoint]:
    name = _object_name(sim)
    nut = sim.object_poses()[name]
    start_yaw = yaw_of(sim.robot_state().end_effector)
    # The handle sticks out along the nut's x axis: close the fingers across it.
    yield from _pick(sim, f"{name}/handle", yaw_of(nut) + np.pi / 2, np.pi)
    hand = sim.robot_state().end_effector
    nut = sim.object_poses()[name]
    peg = sim.object_poses()[f"{name}/target"]
    # A square hole slides down its square peg only when turned to match it: of the turns that
    # do, take the one leaving the wrist nearest its start (a wrist turned further stalls).
    turn = 0.0
    if (period := NUT_SYMMETRY[name]) is not None:
        turn = yaw_of(peg) - yaw_of(nut)
        wrist = yaw_of(hand) + turn - start_yaw
        turn -= period * round(((wrist + np.pi) % (2 * np.pi) - np.pi) / period)
    spin = Rotation.from_euler("z", turn)
    carried = spin * hand.rotation
    offset = spin.apply(nut.position - hand.position)  # nut centre from the hand, once turned
    carry_z = peg.position[2] + 0.20 - offset[2]
    over_peg = peg.position[:2] - offset[:2]
    yield Waypoint(at([*hand.position[:2], carry_z], hand.rotation), True, 0.02, label="lift")
    yield Waypoint(at([*over_peg, carry_z], carried), True, 0.01, 0.3, label="carry")
    low_z = peg.position[2] + 0.02 - offset[2]
    yield Waypoint(at([*over_peg, low_z], carried), True, 0.015, label="lower")
    yield Waypoint(at([*over_peg, low_z], carried), False, 0.05, 0.3, label="release")
    yield Waypoint(at([*over_peg, carry_z], carried), False, 0.03, label="retreat")


STACK_CLEARANCE_M = 0.05
STACK_RELEASE_ABOVE_M = 0.005


def stack(sim: ScriptedScene) -> Iterator[Waypoint]:
    """Pick cubeA as in lift, carry it over cubeB, set it down there, let go and back off."""
    poses = sim.object_poses()
    table_z = poses["table"].position[2]
    # resting on cubeB, cubeA's centre is both cubes' half heights above cubeB's centre
    half_heights = poses["cubeA"].position[2] + poses["cubeB"].position[2] - 2 * table_z
    yield from _pick(sim, "cubeA", yaw_of(poses["cubeA"]), np.pi / 2)
    hand = sim.robot_state().end_effector
    poses = sim.object_poses()
    offset = poses["cubeA"].position - hand.position  # held cube's centre from the hand
    rest = poses["cubeB"].position + [0.0, 0.0, half_heights] - offset
    carry_z = rest[2] + STACK_CLEARANCE_M
    release_z = rest[2] + STACK_RELEASE_ABOVE_M
    yield Waypoint(at([*hand.position[:2], carry_z], hand.rotation), True, 0.02, label="lift")
    yield Waypoint(at([*rest[:2], carry_z], hand.rotation), True, 0.01, 0.3, label="carry")
    yield Waypoint(at([*rest[:2], release_z], hand.rotation), True, 0.006, label="lower")
    yield Waypoint(at([*rest[:2], release_z], hand.rotation), False, 0.05, 0.4, label="release")
    yield Waypoint(at([*rest[:2], carry_z], hand.rotation), False, 0.03, label="retreat")


PLANS: dict[str, Plan] = {
    "lift": lift,
    "mujoco-lift": lift,
    "pick-place-can": pick_place,
    "pick-place-milk": pick_place,
    "pick-place-bread": pick_place,
    "pick-place-cereal": pick_place,
    "nut-assembly-round": nut_assembly,
    "nut-assembly-square": nut_assembly,
    "stack": stack,
}


# The plans a task declared elsewhere may name (`TaskSpec.operator_plan`).
NAMED_PLANS: dict[str, Plan] = {
    "lift": lift,
    "pick-place": pick_place,
    "nut-assembly": nut_assembly,
    "stack": stack,
}


def plan_for(task: str) -> Plan:
    """The built-in task's plan, or the one its declaration names (by name or reference)."""
    if task in PLANS:
        return PLANS[task]
    declared = get_task(task).operator_plan
    if declared is None:
        raise ConfigError(
            f"no scripted operator for task {task!r}: declare its operator_plan (one of "
            f"{', '.join(NAMED_PLANS)}, or 'package.module:plan'); built-in: {', '.join(PLANS)}"
        )
    if ":" in declared:
        plan: Plan = resolve(declared)
        return plan
    try:
        return NAMED_PLANS[declared]
    except KeyError:
        raise ConfigError(
            f"task {task!r} names operator_plan {declared!r}; choose one of "
            f"{', '.join(NAMED_PLANS)} or 'package.module:plan'"
        ) from None
