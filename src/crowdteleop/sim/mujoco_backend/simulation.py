"""`Simulation` on the bare `mujoco` bindings: proof that the interface needs no robosuite.

Mirrors `RobosuiteSimulation` (validation, cold solver start per control step, contact events)
on the hand-written scene of `scene.py`. Only ``joint-velocity`` actions are supported: they map
directly onto the scene's joint-velocity servos, so no controller code is needed.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np
import numpy.typing as npt

from crowdteleop.errors import (
    ConfigError,
    InvalidStateError,
    UnknownRobotError,
)
from crowdteleop.sim.config import SimConfig
from crowdteleop.sim.contacts import ContactReader, body_subtree_geoms
from crowdteleop.sim.declared import DeclaredChecks, generic_progress
from crowdteleop.sim.mujoco_backend import scene
from crowdteleop.sim.mujoco_backend.objects import MujocoScene, SceneObjects
from crowdteleop.sim.mujoco_data import flat_state, pose_from_matrix
from crowdteleop.sim.rendering import CameraRenderer
from crowdteleop.sim.types import (
    ActionSpec,
    ContactEvent,
    KinematicModel,
    Marker,
    Pose,
    RobotState,
    StepResult,
    TaskProgress,
    validate_state,
)
from crowdteleop.tasks import TaskSpec, get_task, read_scene

# The scene has one arm of its own; "Sawyer" (SimConfig's default) is accepted so a config
# written for the robosuite backend only needs its task changed.
ROBOTS = ("mujoco-arm", "Sawyer")
LIFT_SUCCESS_HEIGHT = 0.04  # m above the cube's resting height
IDENTITY_QUAT = np.array([0.0, 0.0, 0.0, 1.0])


class MujocoSimulation:
    """A pure-MuJoCo scene behind the `Simulation` interface: lift, or a plug-in's objects."""

    def __init__(self, config: SimConfig) -> None:
        if config.robot not in ROBOTS:
            raise UnknownRobotError(
                f"unknown robot {config.robot!r} for the mujoco backend; its scene has one arm, "
                f"named one of: {', '.join(ROBOTS)}"
            )
        if config.action_mode != "joint-velocity":
            raise ConfigError(
                f"the mujoco backend supports action_mode 'joint-velocity' only, got "
                f"{config.action_mode!r}; use a robosuite task (e.g. 'lift') for 'osc-pose'"
            )
        if config.robosuite_step:
            raise ConfigError(f"task {config.task!r} runs on plain MuJoCo: no robosuite to step")
        self.config = config
        self.task: TaskSpec = get_task(config.task)
        if self.task.backend != "mujoco":
            raise ConfigError(
                f"task {config.task!r} belongs to the {self.task.backend} backend, not mujoco"
            )
        if self.task.scene is None:
            self._xml, objects = scene.scene_xml(self.task.env_name), ["cube"]
        else:
            self._xml, objects = scene.objects_scene_xml(read_scene(self.task), self.task.name)
        try:
            self._model = mujoco.MjModel.from_xml_string(self._xml)
        except ValueError as error:
            raise ConfigError(
                f"task {self.task.name!r}: its scene does not compile: {error}"
            ) from None
        self._data = mujoco.MjData(self._model)
        model = self._model
        self._substeps = max(1, round(1.0 / (config.control_hz * model.opt.timestep)))
        self._renderer = CameraRenderer(model)
        self.cameras = self._renderer.cameras
        self._init_indices()
        self._objects = SceneObjects(model, objects)
        self._rest_z = float(self._objects.items[0].home[2])  # lift: the cube on the table
        self.declared = DeclaredChecks(self.task, MujocoScene(model, self._data))
        n = len(scene.ARM_JOINTS)
        speed = config.max_joint_speed
        self.action_spec = ActionSpec(
            "joint-velocity",
            n + 1,
            np.append(np.full(n, -speed), -1.0),
            np.append(np.full(n, speed), 1.0),
        )
        self._contacts = self._make_contact_reader()
        self.contact_objects = self._contacts.objects
        self._closed = False
        self.reset()

    def _init_indices(self) -> None:
        model = self._model
        arm = [model.joint(name).id for name in scene.ARM_JOINTS]
        self._arm_joint_ids = np.array(arm)
        self._arm_qpos = model.jnt_qposadr[arm]
        self._arm_dofs = model.jnt_dofadr[arm]
        servos = [model.actuator(f"{name}_servo").id for name in scene.ARM_JOINTS]
        self._servo_ctrl = np.array(servos)
        self._servo_act = model.actuator_actadr[servos]
        self._velocity_ctrl = np.array(
            [model.actuator(f"{name}_velocity").id for name in scene.ARM_JOINTS]
        )
        fingers = [model.joint(name).id for name in scene.FINGER_JOINTS]
        self._finger_qpos = model.jnt_qposadr[fingers]
        self._finger_dofs = model.jnt_dofadr[fingers]
        self._finger_ctrl = np.array(
            [model.actuator(f"{name}_position").id for name in scene.FINGER_JOINTS]
        )
        self._pad_geoms = tuple(model.geom(name).id for name in scene.FINGER_PADS)
        self._ee_site_id = model.site("ee_site").id
        self._base_body_id = model.body("robot_base").id

    # --- lifecycle -------------------------------------------------------------------------
    @property
    def control_dt(self) -> float:
        return float(self._substeps * self._model.opt.timestep)

    def reset(self, seed: int | None = None) -> None:
        rng = np.random.default_rng(seed)
        model, data = self._model, self._data
        mujoco.mj_resetData(model, data)
        data.qpos[self._arm_qpos] = scene.HOME_QPOS
        data.qpos[self._finger_qpos] = 0.0
        self._objects.place(data, rng)
        data.act[self._servo_act] = scene.HOME_QPOS
        mujoco.mj_forward(model, data)

    def close(self) -> None:
        if not self._closed:
            self._renderer.close()
            self._closed = True

    # --- stepping --------------------------------------------------------------------------
    def step(self, action: npt.NDArray[np.float64]) -> StepResult:
        action = self.action_spec.validate(action)
        qdot, gripper = action[:-1], action[-1]
        data = self._data
        # Cold solver start (see RobosuiteSimulation.step) and a servo set point re-anchored at
        # the measured joints: the step depends on [time, qpos, qvel] and the action alone.
        data.qacc_warmstart[:] = 0.0
        data.act[self._servo_act] = data.qpos[self._arm_qpos]
        data.ctrl[self._servo_ctrl] = qdot
        data.ctrl[self._velocity_ctrl] = qdot
        data.ctrl[self._finger_ctrl] = (gripper + 1.0) / 2.0 * scene.FINGER_TRAVEL
        mujoco.mj_step(self._model, data, nstep=self._substeps)
        # mj_step leaves kinematics and contacts one substep stale; observe the new state.
        mujoco.mj_forward(self._model, data)
        success = self.success()
        return StepResult(float(success), success, self.contacts(), self._progress(success))

    def success(self) -> bool:
        """The task's own test where it declares one, else lift's: the cube 4 cm up."""
        if self.declared.declares_success:
            return self.declared.success()
        cube_z = self._data.xpos[self._objects.items[0].body][2]
        return bool(cube_z > self._rest_z + LIFT_SUCCESS_HEIGHT)

    # --- state -----------------------------------------------------------------------------
    def get_state(self) -> npt.NDArray[np.float64]:
        return flat_state(self._model, self._data)

    def set_state(self, state: npt.NDArray[np.float64]) -> None:
        nq, nv = self._model.nq, self._model.nv
        state = validate_state(state, 1 + nq + nv)
        data = self._data
        data.time = state[0]
        data.qpos[:] = state[1 : 1 + nq]
        data.qvel[:] = state[1 + nq :]
        data.act[self._servo_act] = data.qpos[self._arm_qpos]
        mujoco.mj_forward(self._model, data)

    def controller_state(self) -> npt.NDArray[np.float64]:
        """None: the fingers follow each action directly (shape (0,))."""
        return np.zeros(0)

    def set_controller_state(self, value: npt.NDArray[np.float64]) -> None:
        if np.asarray(value).size != 0:
            raise InvalidStateError("this scene's controller keeps no state between steps")

    def observations(self) -> dict[str, npt.NDArray[np.float64]]:
        """robosuite Lift's keys for this scene (object: per object its position, quaternion
        (x, y, z, w) and position minus the hand's)."""
        data, robot = self._data, self.robot_state()
        hand = robot.end_effector.position
        return {
            "object": self._objects.observation(data, hand),
            "robot0_joint_pos": robot.joint_positions,
            "robot0_joint_pos_cos": np.cos(robot.joint_positions),
            "robot0_joint_pos_sin": np.sin(robot.joint_positions),
            "robot0_joint_vel": robot.joint_velocities,
            "robot0_eef_pos": hand.copy(),
            "robot0_eef_quat": robot.end_effector.quaternion.copy(),
            "robot0_gripper_qpos": data.qpos[self._finger_qpos].copy(),
            "robot0_gripper_qvel": data.qvel[self._finger_dofs].copy(),
        }

    # --- observation -----------------------------------------------------------------------
    def render(
        self, camera: str, width: int, height: int, markers: Sequence[Marker] = ()
    ) -> npt.NDArray[np.uint8]:
        return self._renderer.render(self._data, camera, width, height, markers)

    def contacts(self) -> list[ContactEvent]:
        return self._contacts.read(self._data)

    def progress(self) -> TaskProgress:
        return self._progress(self.success())

    def _progress(self, success: bool) -> TaskProgress:
        if self.declared.declares_stages:
            return self.declared.staged_progress(success)
        if self.declared.declares_success:
            held = self._objects.held(self._data, self._pad_geoms)
            return generic_progress(self.task.instruction, success, held)
        if success:
            return TaskProgress("done", "Cube lifted: well done!", 2, 2)
        cube = self._objects.items[0].name
        if self._grasped():
            return TaskProgress("grasped", "Cube grasped: now lift it.", 1, 2, cube)
        return TaskProgress("reach", "Reach for the cube and grasp it.", 0, 2, cube)

    def _grasped(self) -> bool:
        """Both finger pads touch the cube."""
        return bool(self._objects.held(self._data, self._pad_geoms))

    def robot_state(self) -> RobotState:
        data = self._data
        fingers = data.qpos[self._finger_qpos] / scene.FINGER_TRAVEL
        return RobotState(
            joint_positions=data.qpos[self._arm_qpos].copy(),
            joint_velocities=data.qvel[self._arm_dofs].copy(),
            end_effector=pose_from_matrix(
                data.site_xpos[self._ee_site_id], data.site_xmat[self._ee_site_id]
            ),
            base=pose_from_matrix(data.xpos[self._base_body_id], data.xmat[self._base_body_id]),
            gripper_closed_fraction=float(np.clip(np.mean(fingers), 0.0, 1.0)),
            end_effector_velocity=self._site_velocity(),
        )

    def _site_velocity(self) -> npt.NDArray[np.float64]:
        """(linear, angular) world-frame velocity of ``ee_site``; MuJoCo gives (angular, linear)."""
        angular_linear = np.zeros(6)
        mujoco.mj_objectVelocity(
            self._model, self._data, mujoco.mjtObj.mjOBJ_SITE, self._ee_site_id, angular_linear, 0
        )
        return np.concatenate([angular_linear[3:], angular_linear[:3]])

    def object_poses(self) -> dict[str, Pose]:
        table = Pose(np.array([0.0, 0.0, scene.TABLE_TOP_Z]), IDENTITY_QUAT.copy())
        return self._objects.poses(self._data) | {"table": table}

    def kinematics(self) -> KinematicModel:
        return KinematicModel(
            mjcf_xml=self.mjcf_xml(),
            arm_joints=scene.ARM_JOINTS,
            end_effector_site="ee_site",
            joint_position_limits=self._model.jnt_range[self._arm_joint_ids].copy(),
            joint_velocity_limits=np.full(len(scene.ARM_JOINTS), self.config.max_joint_speed),
            state_index=tuple(1 + int(a) for a in self._model.jnt_qposadr[self._arm_joint_ids]),
        )

    def mjcf_xml(self) -> str:
        return self._xml

    # --- construction helpers --------------------------------------------------------------
    def _make_contact_reader(self) -> ContactReader:
        model = self._model
        robot_geoms = {
            geom: model.body(model.geom_bodyid[geom]).name
            for geom in body_subtree_geoms(model, [self._base_body_id])
        }
        return ContactReader(model, robot_geoms, self._objects.contact_names(model))
