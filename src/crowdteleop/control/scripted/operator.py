"""A scripted operator: follows a plan's waypoints by moving a virtual phone, clutch and all.

Its `OperatorStyle` makes it as human as wanted: slower, shaky (tremor), slow to react, past
the mark and back (overshoot and correction), lost in thought (idle pauses), unsure of a grasp
(gripper chatter) and clumsy (a drop while carrying). `skills.SKILLS` names three levels.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
from pydantic import BaseModel, ConfigDict, Field
from scipy.spatial.transform import Rotation, Slerp

from crowdteleop.control.command import DeviceCommand
from crowdteleop.control.config import MappingConfig
from crowdteleop.control.mapping import ClutchMapper
from crowdteleop.control.scripted.plans import DESCEND, ScriptedScene, plan_for
from crowdteleop.control.scripted.waypoints import Waypoint
from crowdteleop.sim.types import Pose

CHATTER_CLOSED_S = 0.2  # a hesitant grasp: the gripper closes this long, then
CHATTER_OPEN_S = 0.3  # opens this long, once or twice, before it closes for good
# A drop: a quarter of the way along a carrying leg (early enough that a lift has not yet
# counted as a success), the gripper opens this long, then closes again (on nothing).
DROP_AT_FRACTION = 0.25
DROP_OPEN_S = 0.5
# A hand held up short of a mark: still within this (the Panda under OSC trembles ~6 mm at
# 10 Hz while it waits; a hand on its way moves ~10 mm a step)
STILL_M = 0.01


class OperatorStyle(BaseModel):
    """How human the operator looks. The defaults are a calm, steady person, and exactly the
    operator of before the human traits: a trait at its default draws no random numbers, so a
    seed drives the same episode it always did."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    speed_m_s: float = Field(0.25, gt=0, le=2.0, description="hand speed")
    turn_rad_s: float = Field(1.5, gt=0, le=10.0, description="hand turning speed")
    tremor_m: float = Field(0.0, ge=0, le=0.02, description="std of slow positional tremor")
    hesitation_probability: float = Field(
        0.0, ge=0, le=1, description="chance to pause per waypoint"
    )
    hesitation_s: tuple[float, float] = (0.2, 1.0)
    reaction_s: float = Field(
        0.0, ge=0, le=5.0, description="pause before setting off to each new waypoint (s)"
    )
    overshoot_fraction: float = Field(
        0.0,
        ge=0,
        le=1.0,
        description="aim past a waypoint by this fraction of the leg's length, then come back "
        "(never below the waypoint's height: no pushing into the table)",
    )
    overshoot_probability: float = Field(
        1.0, ge=0, le=1, description="chance per waypoint that an overshoot happens"
    )
    idle_probability: float = Field(
        0.0, ge=0, le=1, description="chance per waypoint of a long idle pause before it"
    )
    idle_s: tuple[float, float] = (3.0, 10.0)
    hesitant_grasp_probability: float = Field(
        0.0,
        ge=0,
        le=1,
        description="chance per grasp that the gripper closes and reopens once or twice "
        "within about a second before it closes for good (gripper chatter)",
    )
    drop_probability: float = Field(
        0.0,
        ge=0,
        le=1,
        description="chance per carrying waypoint (gripper closed before and after) that the "
        "gripper opens once on the way there: the object drops, the plan goes on",
    )
    grasp_idle_s: float = Field(
        0.0, ge=0, le=60.0, description="an idle pause this long before the first grasp"
    )
    detour_m: float = Field(
        0.0,
        ge=0,
        le=0.5,
        description="on the first leg, the hand first wanders this far sideways (and half as "
        "far up), then heads for the waypoint",
    )
    drop_once: bool = Field(
        False, description="drop what it carries on the first carrying leg, whatever the odds"
    )
    press_m: float = Field(
        0.0,
        ge=0,
        le=0.2,
        description="on the way down to the first grasp, the hand is pushed this far below "
        "the grasp point (into the table), then comes back up to it",
    )
    device_origin: tuple[float, float, float] = (0.1, -0.2, 1.2)  # where the phone starts


@dataclass
class _Leg:
    """Progress toward the current waypoint."""

    waypoint: Waypoint
    start: Pose
    elapsed_s: float = 0.0
    dwell_s: float = 0.0
    pause_s: float = 0.0  # hesitation: counts toward the waypoint's timeout
    wait_s: float = 0.0  # reaction and idle time: does not count toward the timeout
    aim: Pose | None = None  # the overshoot target, until the hand has reached it
    # gripper chatter still to do: (seconds, closed) segments before the waypoint's gripper
    chatter: list[tuple[float, bool]] = field(default_factory=list)
    drop_after_m: float | None = None  # open the gripper once the hand has moved this far
    drop_s: float = 0.0  # the gripper is open for a drop this much longer
    # where the hand has stayed (within STILL_M) since its commanded pose reached the mark
    still_at: npt.NDArray[np.float64] | None = None
    still_s: float = 0.0


class ScriptedOperator:
    """Produces one `DeviceCommand` per control step for `sim`'s task."""

    def __init__(
        self,
        sim: ScriptedScene,
        mapping: MappingConfig | None = None,
        style: OperatorStyle | None = None,
        seed: int | None = None,
    ) -> None:
        self.sim = sim
        self.style = style or OperatorStyle()
        self._plan_factory = plan_for(sim.config.task)
        self._mapper = ClutchMapper(mapping or MappingConfig())
        self._rng = np.random.default_rng(seed)
        self._dt = sim.control_dt
        self.reset()

    def reset(self) -> None:
        """Forget the episode: call after the simulation resets."""
        self._mapper.reset()
        self._plan: Iterator[Waypoint] | None = None
        self._leg: _Leg | None = None
        self._hand: Pose | None = None  # the pose the operator is currently commanding
        self._gripper_closed = False
        self._tremor = np.zeros(3)
        self._seq = 0
        self.finished = False
        # the injected faults still to make this episode (OperatorStyle: grasp_idle_s,
        # detour_m, drop_once): each happens once
        self._faults = {
            "idle": self.style.grasp_idle_s > 0,
            "detour": self.style.detour_m > 0,
            "drop": self.style.drop_once,
            "press": self.style.press_m > 0,
        }

    @property
    def anchored(self) -> bool:
        """Whether the clutch press that anchors the device to the arm has been issued."""
        return self._plan is not None

    @property
    def waypoint(self) -> Waypoint | None:
        """The waypoint the operator is heading for (None before the first, after the last)."""
        return None if self._leg is None or self.finished else self._leg.waypoint

    @property
    def stage(self) -> str:
        return self._leg.waypoint.label if self._leg else "start"

    def command(self) -> DeviceCommand:
        """The next command, for the state the simulation is in now."""
        self._seq += 1
        end_effector = self.sim.robot_state().end_effector
        if self._plan is None:
            return self._engage(end_effector)
        self._advance(end_effector)
        assert self._hand is not None
        device = self._mapper.device_pose_for(self._hand)
        self._tremor = 0.9 * self._tremor + np.sqrt(1 - 0.81) * self._rng.normal(
            0.0, self.style.tremor_m, 3
        )
        return DeviceCommand(
            position=device.position + self._tremor,
            quaternion=device.quaternion,
            engaged=True,
            gripper_closed=self._gripper_closed,
            seq=self._seq,
            client_time_ms=1000.0 * self._seq * self._dt,
        )

    # --- internals -------------------------------------------------------------------------
    def _engage(self, end_effector: Pose) -> DeviceCommand:
        origin = DeviceCommand(
            position=np.array(self.style.device_origin), engaged=True, seq=self._seq
        )
        self._mapper.target(origin, end_effector)  # anchor exactly as the teleoperator will
        self._hand = end_effector
        self._plan = self._plan_factory(self.sim)
        return origin

    def _advance(self, end_effector: Pose) -> None:
        if self._leg is None and not self._next_leg():
            return
        leg = self._leg
        assert leg is not None and self._hand is not None
        if leg.wait_s > 0:
            leg.wait_s -= self._dt
            return
        leg.elapsed_s += self._dt
        if leg.pause_s > 0:
            leg.pause_s -= self._dt
            return
        self._hand = self._move_toward(self._hand, leg.aim or leg.waypoint.pose)
        if leg.aim is not None and np.array_equal(self._hand.position, leg.aim.position):
            leg.aim = None  # past the mark: correct back to it
        self._gripper_closed = self._gripper_for(leg)
        if leg.aim is not None or leg.chatter:
            return  # neither overshot nor done hesitating: not there yet
        held_short = self._held_short(leg, end_effector)
        arrived = held_short or (
            np.linalg.norm(end_effector.position - leg.waypoint.pose.position)
            < leg.waypoint.tolerance_m
        )
        if arrived or leg.elapsed_s > leg.waypoint.timeout_s:
            leg.dwell_s += self._dt
            if leg.dwell_s >= leg.waypoint.dwell_s:
                self._next_leg()

    def _held_short(self, leg: _Leg, end_effector: Pose) -> bool:
        """Whether the hand has stood still short of the mark for the waypoint's ``stall_s``
        while the command was already there: something (a floor, the object it nudged) holds
        it up, and waiting out the timeout would only add idle steps to the demonstration,
        then close the gripper where it is all the same."""
        waypoint = leg.waypoint
        assert self._hand is not None
        if waypoint.stall_s is None or not np.array_equal(
            self._hand.position, waypoint.pose.position
        ):
            return False
        here = end_effector.position
        if leg.still_at is None or np.linalg.norm(here - leg.still_at) > STILL_M:
            leg.still_at, leg.still_s = here.copy(), 0.0
        else:
            leg.still_s += self._dt
        return leg.still_s >= waypoint.stall_s

    def _next_leg(self) -> bool:
        assert self._plan is not None and self._hand is not None
        waypoint = next(self._plan, None)
        if waypoint is None:
            self.finished = True
            return False
        pause = 0.0
        if self._rng.random() < self.style.hesitation_probability:
            pause = self._rng.uniform(*self.style.hesitation_s)
        grasp = waypoint.gripper_closed and not self._gripper_closed
        self._leg = _Leg(waypoint, self._hand, pause_s=pause, wait_s=self._wait(grasp))
        self._leg.aim = self._detour() or self._press(waypoint) or self._overshoot(waypoint)
        if grasp:
            self._leg.chatter = self._chatter()
        elif waypoint.gripper_closed and (
            self._fault("drop") or self._chance(self.style.drop_probability)
        ):
            length = float(np.linalg.norm(waypoint.pose.position - self._hand.position))
            self._leg.drop_after_m = DROP_AT_FRACTION * length
        return True

    # --- human traits ----------------------------------------------------------------------
    def _chance(self, probability: float) -> bool:
        """A draw that happens: no random number is drawn for a trait that cannot happen, so
        styles without it keep the exact episodes of their seeds."""
        if probability <= 0.0:
            return False
        return probability >= 1.0 or bool(self._rng.random() < probability)

    def _fault(self, name: str) -> bool:
        """Whether the injected fault `name` is due now (then it is spent for the episode)."""
        due = self._faults[name]
        self._faults[name] = False
        return due

    def _wait(self, grasp: bool) -> float:
        """Reaction time, and now and then a long idle pause, before setting off (and the
        injected idle before the first grasp)."""
        wait = self.style.reaction_s
        if self._chance(self.style.idle_probability):
            wait += float(self._rng.uniform(*self.style.idle_s))
        if grasp and self._fault("idle"):
            wait += self.style.grasp_idle_s
        return wait

    def _detour(self) -> Pose | None:
        """The injected detour's turning point on the first leg (None once made, or never)."""
        assert self._hand is not None
        if not self._fault("detour"):
            return None
        offset = np.array([0.0, self.style.detour_m, 0.5 * self.style.detour_m])
        return Pose(self._hand.position + offset, self._hand.quaternion)

    def _press(self, waypoint: Waypoint) -> Pose | None:
        """The injected press's lowest point, below the descent to the first grasp (None once
        made, or never)."""
        if waypoint.label != DESCEND or not self._fault("press"):
            return None
        return Pose(
            waypoint.pose.position - [0.0, 0.0, self.style.press_m], waypoint.pose.quaternion
        )

    def _overshoot(self, waypoint: Waypoint) -> Pose | None:
        """Where to aim past `waypoint` along the leg (None: straight there), never below it."""
        assert self._hand is not None
        if self.style.overshoot_fraction <= 0 or not self._chance(self.style.overshoot_probability):
            return None
        goal = waypoint.pose.position
        aim = goal + self.style.overshoot_fraction * (goal - self._hand.position)
        aim[2] = max(aim[2], goal[2])
        if np.linalg.norm(aim - goal) < 1e-6:
            return None  # a turn on the spot, or straight down: nothing to overshoot
        return Pose(aim, waypoint.pose.quaternion)

    def _chatter(self) -> list[tuple[float, bool]]:
        """A hesitant grasp's gripper: closed and open again, once or twice."""
        if not self._chance(self.style.hesitant_grasp_probability):
            return []
        times = int(self._rng.integers(1, 3))
        return [(CHATTER_CLOSED_S, True), (CHATTER_OPEN_S, False)] * times

    def _gripper_for(self, leg: _Leg) -> bool:
        """The gripper this step: chattering, dropping, or as the waypoint wants it."""
        if leg.chatter:
            seconds, closed = leg.chatter[0]
            seconds -= self._dt
            leg.chatter[0] = (seconds, closed)
            if seconds <= 1e-9:
                leg.chatter.pop(0)
            return closed
        assert self._hand is not None
        if leg.drop_after_m is not None and (
            np.linalg.norm(self._hand.position - leg.start.position) >= leg.drop_after_m
        ):
            leg.drop_after_m, leg.drop_s = None, DROP_OPEN_S
        if leg.drop_s > 0:
            leg.drop_s -= self._dt
            return False
        return leg.waypoint.gripper_closed

    def _move_toward(self, hand: Pose, goal: Pose) -> Pose:
        """One control period of steady hand motion toward `goal`."""
        step = goal.position - hand.position
        distance = float(np.linalg.norm(step))
        max_move = self.style.speed_m_s * self._dt
        position = (
            goal.position if distance <= max_move else hand.position + step * (max_move / distance)
        )
        angle = (goal.rotation * hand.rotation.inv()).magnitude()
        fraction = min(1.0, self.style.turn_rad_s * self._dt / angle) if angle > 1e-9 else 1.0
        both = Rotation.concatenate([hand.rotation, goal.rotation])
        rotation = Slerp([0.0, 1.0], both)(fraction)
        return Pose(position, rotation.as_quat())
