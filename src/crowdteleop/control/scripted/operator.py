"""A scripted operator: follows a plan's waypoints by moving a virtual phone, clutch and all."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.spatial.transform import Rotation, Slerp

from crowdteleop.control.command import DeviceCommand
from crowdteleop.control.config import MappingConfig
from crowdteleop.control.mapping import ClutchMapper
from crowdteleop.control.scripted.plans import ScriptedScene, plan_for
from crowdteleop.control.scripted.waypoints import Waypoint
from crowdteleop.sim.types import Pose


class OperatorStyle(BaseModel):
    """How human the operator looks. The defaults are a calm, steady person."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    speed_m_s: float = Field(0.25, gt=0, le=2.0, description="hand speed")
    turn_rad_s: float = Field(1.5, gt=0, le=10.0, description="hand turning speed")
    tremor_m: float = Field(0.0, ge=0, le=0.02, description="std of slow positional tremor")
    hesitation_probability: float = Field(
        0.0, ge=0, le=1, description="chance to pause per waypoint"
    )
    hesitation_s: tuple[float, float] = (0.2, 1.0)
    device_origin: tuple[float, float, float] = (0.1, -0.2, 1.2)  # where the phone starts


@dataclass
class _Leg:
    """Progress toward the current waypoint."""

    waypoint: Waypoint
    start: Pose
    elapsed_s: float = 0.0
    dwell_s: float = 0.0
    pause_s: float = 0.0


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

    @property
    def anchored(self) -> bool:
        """Whether the clutch press that anchors the device to the arm has been issued."""
        return self._plan is not None

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
        leg.elapsed_s += self._dt
        if leg.pause_s > 0:
            leg.pause_s -= self._dt
            return
        self._hand = self._move_toward(self._hand, leg.waypoint.pose)
        self._gripper_closed = leg.waypoint.gripper_closed
        arrived = (
            np.linalg.norm(end_effector.position - leg.waypoint.pose.position)
            < leg.waypoint.tolerance_m
        )
        if arrived or leg.elapsed_s > leg.waypoint.timeout_s:
            leg.dwell_s += self._dt
            if leg.dwell_s >= leg.waypoint.dwell_s:
                self._next_leg()

    def _next_leg(self) -> bool:
        assert self._plan is not None and self._hand is not None
        waypoint = next(self._plan, None)
        if waypoint is None:
            self.finished = True
            return False
        pause = 0.0
        if self._rng.random() < self.style.hesitation_probability:
            pause = self._rng.uniform(*self.style.hesitation_s)
        self._leg = _Leg(waypoint, self._hand, pause_s=pause)
        return True

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
