"""The paper's controller: desired end-effector pose -> IK set point q* -> qdot = -kv (q - q*).

Inverse kinematics is mink's differential IK (a QP with joint limits) on a private copy of the
scene's MJCF model that keeps only the robot's joints (objects' free joints go), iterated a few
times from the current configuration each control step.
"""

from __future__ import annotations

import mink
import mujoco
import numpy as np
import numpy.typing as npt
import qpsolvers  # mink's QP front end

from crowdteleop.sim.mjcf import kinematics_only, without_free_joints
from crowdteleop.sim.types import KinematicModel, Pose, RobotState
from crowdteleop.vocab import ActionMode

IK_ITERATIONS = 1  # one Gauss-Newton step per control step; the next step refines it
IK_STEP_S = 1.0  # each iteration takes a full Gauss-Newton step toward the target
POSITION_TOLERANCE_M = 5e-4


class IKVelocityController:
    action_mode: ActionMode = "joint-velocity"

    def __init__(self, kinematics: KinematicModel, kv: float) -> None:
        self.kv = kv
        xml = without_free_joints(kinematics_only(kinematics.mjcf_xml))
        self._model = mujoco.MjModel.from_xml_string(xml)
        joint_ids = [self._model.joint(name).id for name in kinematics.arm_joints]
        self._arm_qpos = self._model.jnt_qposadr[joint_ids]
        self._arm_dofs = self._model.jnt_dofadr[joint_ids]
        self._speed_limits = np.asarray(kinematics.joint_velocity_limits, dtype=float)
        self._configuration = mink.Configuration(self._model)
        self._ee_task = mink.FrameTask(
            frame_name=kinematics.end_effector_site,
            frame_type="site",
            position_cost=1.0,
            orientation_cost=0.3,
            lm_damping=1e-2,
        )
        # Keep the 7th joint's null space near the current posture instead of wandering.
        self._posture_task = mink.PostureTask(self._model, cost=1e-3)
        self._limits = [mink.ConfigurationLimit(self._model)]
        # Only the arm moves in the IK: the fingers' velocities are dropped after each solve.
        self._other_dofs = np.setdiff1d(np.arange(self._model.nv), self._arm_dofs)
        self._site_id = self._model.site(kinematics.end_effector_site).id
        self.reset()

    def reset(self) -> None:
        self._last_target: Pose | None = None
        self._last_setpoint = np.zeros(len(self._arm_qpos))

    def joint_setpoint(self, target: Pose, robot: RobotState) -> npt.NDArray[np.float64]:
        """q*: arm joint positions that put the end effector at `target`."""
        q = self._model.qpos0.copy()
        q[self._arm_qpos] = robot.joint_positions
        self._configuration.update(q)
        self._posture_task.set_target(q)
        wxyz = np.roll(target.quaternion, 1)
        self._ee_task.set_target(
            mink.SE3.from_rotation_and_translation(mink.SO3(wxyz), target.position)
        )
        for _ in range(IK_ITERATIONS):
            # `mink.solve_ik` minus its `check_limits` (a per-joint Python loop that only logs
            # warnings: ~15% of the solve, every control step).
            problem = mink.build_ik(
                self._configuration,
                [self._ee_task, self._posture_task],
                IK_STEP_S,
                damping=1e-3,
                limits=self._limits,
            )
            solution = qpsolvers.solve_problem(problem, solver="quadprog").x
            if solution is None:  # quadprog found no solution (mink's solve_ik asserts this)
                raise RuntimeError("the IK quadratic program has no solution")
            velocity = solution / IK_STEP_S
            velocity[self._other_dofs] = 0.0
            self._configuration.integrate_inplace(velocity, IK_STEP_S)
            error = self._configuration.data.site_xpos[self._site_id] - target.position
            if np.linalg.norm(error) < POSITION_TOLERANCE_M:
                break
        setpoint: npt.NDArray[np.float64] = self._configuration.q[self._arm_qpos].copy()
        return setpoint

    def action(
        self, target: Pose, gripper_closed: bool, robot: RobotState
    ) -> npt.NDArray[np.float64]:
        if target is self._last_target:  # holding still (clutch released): same q*, no IK
            q_star = self._last_setpoint
        else:
            q_star = self.joint_setpoint(target, robot)
            self._last_target, self._last_setpoint = target, q_star
        qdot = -self.kv * (robot.joint_positions - q_star)
        qdot = np.clip(qdot, -self._speed_limits, self._speed_limits)
        return np.append(qdot, 1.0 if gripper_closed else -1.0)
