"""One control step of a robosuite scene without robosuite's per-substep Python.

Arm: `FoldedArm` turns the action into actuator settings once; MuJoCo then runs all substeps
with `mj_step(model, data, nstep)`. Gripper: robosuite's GRIP mapping (actuator range centre
plus half-range times the finger command) with robosuite's ramp: the command moves by the
gripper's ``speed`` (0.2 for Sawyer's and Panda's) toward the sign of each action and is kept
between steps, as robosuite's gripper models do, so a recorded gripper action closes the fingers
as fast in plain robosuite as it did here. The ramp is state beside [time, qpos, qvel]
(`FastStepper.gripper_command`); restoring a step exactly needs both. ``gripper_ramp=False``
commands the action's value directly (how recordings made before 2026-12-02 were simulated).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

from crowdteleop.provenance.controllers import ArmController, OscPose
from crowdteleop.sim.robosuite_backend.fast_control import FoldedArm

# A scene whose every joint moves slower than REST_SPEED and, under the step's command,
# accelerates less than REST_ACCEL, stays put for the step: it only advances time, and an idle
# worker's session costs almost nothing. Over 50 ms such a scene would move < 0.3 mm.
REST_SPEED = 5e-3  # rad/s or m/s (resting contacts creep at a few mm/s)
REST_ACCEL = 1e-2  # rad/s^2 or m/s^2


@dataclass(frozen=True)
class Gains:
    """The arm controller's gains, as the fast path applies them."""

    kp: float
    kd: float
    output_max: npt.NDArray[np.float64]  # per action entry: metres / radians (osc), radians (servo)

    @classmethod
    def of(cls, controller: ArmController, arm_actions: int) -> Gains:
        """robosuite's: its stiffness, critical damping times the ratio, and output scale."""
        scale = np.asarray(controller.action_scale, dtype=float)
        return cls(float(controller.kp), controller.kd, np.broadcast_to(scale, arm_actions).copy())


def finger_direction(gripper: Any) -> npt.NDArray[np.float64]:
    """Each finger actuator's command when robosuite's gripper is fully closed (+1 / -1)."""
    saved = np.array(gripper.current_action, copy=True)
    try:
        gripper.current_action = np.zeros_like(saved)
        command = saved
        for _ in range(int(2.0 / gripper.speed) + 2):
            command = gripper.format_action(np.array([1.0]))
        direction: npt.NDArray[np.float64] = np.sign(command)
        return direction
    finally:
        gripper.current_action = saved


class FastStepper:
    def __init__(
        self,
        model: mujoco.MjModel,
        arm: FoldedArm,
        controller: ArmController,
        base_body: int,
        gripper_actuators: npt.NDArray[np.intp],
        gripper_closed: npt.NDArray[np.float64],
        control_dt: float,
        gripper_speed: float | None,
    ) -> None:
        self._model = model
        self.arm = arm
        self._osc_pose = isinstance(controller, OscPose)  # else the joint-velocity servo
        self.gains = Gains.of(controller, 6 if self._osc_pose else len(arm.layout.qpos))
        self._base_body = base_body
        self._gripper_actuators = gripper_actuators
        low, high = model.actuator_ctrlrange[gripper_actuators].T
        self._gripper_centre, self._gripper_half = (high + low) / 2, (high - low) / 2
        self._gripper_closed = gripper_closed
        self._gripper_speed = gripper_speed  # None: no ramp, the action commands the fingers
        self.gripper_command = 0.0  # robosuite's ramped finger command in [-1, 1]
        self.substeps = max(1, round(control_dt / model.opt.timestep))
        self.slept_steps = 0
        self.initial_joints = np.zeros(len(arm.layout.qpos))
        self._asleep_at: tuple[bytes, bytes, bytes, float] | None = None

    def start_episode(self, data: mujoco.MjData) -> None:
        """robosuite's OSC pulls the arm's null space toward the episode's first posture; its
        gripper command starts at 0 after a reset (robosuite rebuilds its gripper models on a
        hard reset, the default, and robomimic's environments reset hard)."""
        self.initial_joints = data.qpos[self.arm.layout.qpos].copy()
        self.gripper_command = 0.0

    def finger_command(self, gripper_action: float) -> float:
        """The finger command after a step with ``gripper_action``: robosuite's ramp."""
        if self._gripper_speed is None:
            return float(gripper_action)
        step = self._gripper_speed * float(np.sign(gripper_action))
        return float(np.clip(self.gripper_command + step, -1.0, 1.0))

    def step(self, data: mujoco.MjData, action: npt.NDArray[np.float64]) -> None:
        # Still asleep: the same positions, velocities and command as the step that slept last
        # decide the same way again, without recomputing anything.
        arm_action = action[:-1]
        gripper = self.finger_command(action[-1])
        self.gripper_command = gripper
        key = (data.qpos.tobytes(), data.qvel.tobytes(), action[:-1].tobytes(), gripper)
        if key == self._asleep_at:
            self._sleep(data)
            return
        if self._osc_pose:
            self._osc(data, arm_action)
        else:
            goal = data.qpos[self.arm.layout.qpos] + arm_action * self.gains.output_max
            self.arm.joint_servo(data, goal, self.gains.kp, self.gains.kd)
        data.ctrl[self._gripper_actuators] = (
            self._gripper_centre + self._gripper_half * self._gripper_closed * gripper
        )
        # MuJoCo warm-starts its constraint solver from the previous step's accelerations, a
        # hidden state outside [time, qpos, qvel]. Starting each control step cold makes the
        # step a function of the recorded state and the action alone (exact restore / replay).
        data.qacc_warmstart[:] = 0.0
        if self._stays_at_rest(data):
            self._asleep_at = key
            self._sleep(data)
            return
        self._asleep_at = None
        mujoco.mj_step(self._model, data, nstep=self.substeps)
        mujoco.mj_forward(self._model, data)  # observe (and linearize next time) at the new q

    def _sleep(self, data: mujoco.MjData) -> None:
        data.time += self.substeps * self._model.opt.timestep
        self.slept_steps += 1

    def _stays_at_rest(self, data: mujoco.MjData) -> bool:
        """Nothing moves and, under the command just applied, nothing would start to: decided
        from the state and action alone, so a restored state sleeps or steps as it did."""
        if np.abs(data.qvel).max() > REST_SPEED:
            return False
        mujoco.mj_forward(self._model, data)  # accelerations under this step's command
        data.qacc_warmstart[:] = 0.0
        return bool(np.abs(data.qacc).max() < REST_ACCEL)

    def _osc(self, data: mujoco.MjData, arm_action: npt.NDArray[np.float64]) -> None:
        """robosuite's OSC_POSE delta goal, input in the base frame, 'achieved' update mode."""
        delta = arm_action * self.gains.output_max
        base = data.xmat[self._base_body].reshape(3, 3)
        site = self.arm.layout.ee_site
        goal_position = data.site_xpos[site] + base @ delta[:3]
        turn = Rotation.from_rotvec(delta[3:]).as_matrix()
        goal_orientation = base @ turn @ base.T @ data.site_xmat[site].reshape(3, 3)
        self.arm.osc(
            data, goal_position, goal_orientation, self.initial_joints, self.gains.kp, self.gains.kd
        )
