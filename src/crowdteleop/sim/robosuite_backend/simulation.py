"""`Simulation` on robosuite: its task classes, robot models and controllers."""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from typing import Any

os.environ.setdefault("PYNPUT_BACKEND", "dummy")  # robosuite.devices wants an X display

import mujoco
import numpy as np
import numpy.typing as npt

from crowdteleop.errors import ConfigError, InvalidStateError, UnknownRobotError
from crowdteleop.provenance.controllers import CompositeController, arm_controller
from crowdteleop.sim import mjcf
from crowdteleop.sim.config import SimConfig
from crowdteleop.sim.contacts import ContactReader, body_subtree_geoms, touching
from crowdteleop.sim.fastrender import FastSceneRenderer
from crowdteleop.sim.mujoco_data import flat_state, pose_from_matrix
from crowdteleop.sim.robosuite_backend import fast_model, model_fixes, tasks
from crowdteleop.sim.robosuite_backend.fast_control import ArmLayout, FoldedArm
from crowdteleop.sim.robosuite_backend.fast_fit import fast_path_obstacles
from crowdteleop.sim.robosuite_backend.fast_step import FastStepper, finger_direction
from crowdteleop.sim.robosuite_backend.judge import TaskJudge
from crowdteleop.sim.robosuite_backend.plain_step import PlainStepper
from crowdteleop.sim.types import (
    ActionSpec,
    ContactEvent,
    KinematicModel,
    Marker,
    Pose,
    RobotState,
    StepResult,
    TaskProgress,
    low_dim_keys,
    validate_state,
)
from crowdteleop.tasks import ROBOSUITE_ARMS, TaskSpec, get_task, import_env_module

logging.getLogger("robosuite").setLevel(logging.ERROR)

COLLISION_GEOM_GROUP = 0  # robosuite draws visual meshes (group 1) and hides collision geoms

logger = logging.getLogger(__name__)


class RobosuiteSimulation:
    """One robosuite environment behind the `Simulation` interface."""

    def __init__(self, config: SimConfig) -> None:
        if config.robot not in ROBOSUITE_ARMS:
            raise UnknownRobotError(
                f"unknown robot {config.robot!r}; choose one of: {', '.join(ROBOSUITE_ARMS)}"
            )
        self.config = config
        self.task: TaskSpec = get_task(config.task)
        if self.task.robots and config.robot not in self.task.robots:
            raise UnknownRobotError(
                f"robot {config.robot!r} does not fit task {self.task.name!r}; it takes "
                f"{', '.join(self.task.robots)}"
            )
        # The arm's controller, as robosuite builds it and as the fast path applies it.
        self._controller = arm_controller(
            config.action_mode, 1.0 / config.control_hz, config.max_joint_speed
        )
        self._env = self._make_env()
        self.fast_path_obstacles = fast_path_obstacles(self._env)
        self.fast_path = self._choose_fast_path()
        self.judge = TaskJudge(self.task, self._env)  # public: its `errors` count
        self._xml = ""
        self._load_fixed_model()
        self._model: mujoco.MjModel = self._env.sim.model._model
        self._loaded_placements = self.body_placements()  # as the XML puts the bodies
        self._data: mujoco.MjData = self._env.sim.data._data
        self._robot = self._env.robots[0]
        self._arm = self._robot.arms[0]
        self._renderer = FastSceneRenderer(self._model, self._xml, (COLLISION_GEOM_GROUP,))
        self.cameras = self._renderer.cameras
        self.action_spec = self._make_action_spec()
        self._arm_qpos_index = np.array(self._robot._ref_joint_pos_indexes)
        self._arm_qvel_index = np.array(self._robot._ref_joint_vel_indexes)
        self._ee_site = self._robot.gripper[self._arm].important_sites["grip_site"]
        self._ee_site_id = self._model.site(self._ee_site).id
        self._base_body_id = self._model.body(self._robot.robot_model.root_body).id
        self._contacts = self._make_contact_reader()
        self.contact_objects = self._contacts.objects
        self._grasped = self._make_grasp_test()
        self._init_gripper_geometry()
        self._stepper = self._make_stepper()
        self._stepper.start_episode(self._data)

    def _make_env(self) -> Any:
        """robosuite's environment for the task, or a `ConfigError` saying why it cannot be."""
        import robosuite

        import_env_module(self.task)
        gripper = self.config.gripper_type
        try:
            return robosuite.make(
                self.task.env_name,
                robots=self.config.robot,
                controller_configs=CompositeController.of(self._controller).to_robosuite(),
                has_renderer=False,
                has_offscreen_renderer=False,
                use_camera_obs=False,
                use_object_obs=True,  # observables only: computed when `observations` asks
                control_freq=self.config.control_hz,
                hard_reset=False,
                ignore_done=True,
                horizon=10**9,
                seed=self.config.model_seed,
                **({} if gripper is None else {"gripper_types": gripper}),
                **self.task.env_kwargs,
            )
        except Exception as error:  # robosuite raises bare Exceptions, and a task's own code
            raise ConfigError(
                f"task {self.task.name!r} ({self.task.source}): robosuite could not build "
                f"{self.task.env_name!r} with robot {self.config.robot!r}: "
                f"{type(error).__name__}: {error}"
            ) from error

    def _choose_fast_path(self) -> bool:
        """The fast path unless the task cannot use it faithfully (or its declaration says
        "off", or the config asks for robosuite's step); "on" with an obstacle is refused,
        "auto" falls back with a warning."""
        obstacles = self.fast_path_obstacles
        if self.task.fast_path == "off" or self.config.robosuite_step:
            return False
        if obstacles and self.task.fast_path == "on":
            raise ConfigError(
                f"task {self.task.name!r} asks for the fast path, which cannot serve it: "
                + "; ".join(obstacles)
            )
        if obstacles:
            logger.warning(
                "task %r runs on robosuite's own path (slower): %s",
                self.task.name,
                "; ".join(obstacles),
            )
        return not obstacles

    # --- lifecycle -------------------------------------------------------------------------
    @property
    def nullspace_posture(self) -> npt.NDArray[np.float64]:
        """The joint posture robosuite's OSC pulls the null space toward: the episode's first.
        Replaying an episode in plain robosuite needs it (it is not in the state)."""
        return self._stepper.initial_joints.copy()

    @property
    def control_dt(self) -> float:
        return float(self._env.control_timestep)

    def reset(self, seed: int | None = None) -> None:
        if seed is not None:
            # Reseed in place: robosuite's placement samplers hold a reference to env.rng.
            self._env.rng.bit_generator.state = np.random.default_rng(seed).bit_generator.state
        self._env.reset()
        self._stepper.start_episode(self._data)

    def close(self) -> None:
        self._renderer.close()
        self._env.close()

    # --- stepping --------------------------------------------------------------------------
    def step(self, action: npt.NDArray[np.float64]) -> StepResult:
        action = self.action_spec.validate(action)
        self._stepper.step(self._data, action)
        with tasks.success_checked_once(self._env):
            reward = self._env.reward(action)
            success = self.success()
            progress = self.judge.progress(success, self._grasped)
        return StepResult(float(reward), success, self.contacts(), progress)

    def success(self) -> bool:
        return self.judge.success()

    # --- state -----------------------------------------------------------------------------
    def get_state(self) -> npt.NDArray[np.float64]:
        """[time, qpos, qvel], robosuite's flattened layout."""
        return flat_state(self._model, self._data)

    def set_state(self, state: npt.NDArray[np.float64]) -> None:
        state = validate_state(state, 1 + self._model.nq + self._model.nv)
        self._env.sim.set_state_from_flattened(state)
        self._env.sim.forward()
        if isinstance(self._stepper, PlainStepper):
            self._stepper.state_loaded()

    def controller_state(self) -> npt.NDArray[np.float64]:
        """robosuite's ramped finger command, kept between steps (shape (1,))."""
        return np.array([self._stepper.gripper_command])

    def set_controller_state(self, value: npt.NDArray[np.float64]) -> None:
        value = np.asarray(value, dtype=float).reshape(-1)
        if value.shape != (1,) or not np.all(np.isfinite(value)) or abs(value[0]) > 1:
            raise InvalidStateError(
                f"controller state must be one finite finger command in [-1, 1], got {value}"
            )
        self._stepper.gripper_command = float(value[0])

    def observations(self) -> dict[str, npt.NDArray[np.float64]]:
        """robosuite's own observables (its sensors, on this data), under robomimic's keys."""
        raw = self._env._get_observations(force_update=True)
        return low_dim_keys(raw, self._robot.robot_model.naming_prefix)

    # --- observation -----------------------------------------------------------------------
    def render(
        self, camera: str, width: int, height: int, markers: Sequence[Marker] = ()
    ) -> npt.NDArray[np.uint8]:
        return self._renderer.render(self._data, camera, width, height, markers)

    def contacts(self) -> list[ContactEvent]:
        return self._contacts.read(self._data)

    def progress(self) -> TaskProgress:
        with tasks.success_checked_once(self._env):
            return self.judge.progress(self.success(), self._grasped)

    def robot_state(self) -> RobotState:
        gripper_closed = self._closed_fraction(self._data)
        return RobotState(
            joint_positions=self._data.qpos[self._arm_qpos_index].copy(),
            joint_velocities=self._data.qvel[self._arm_qvel_index].copy(),
            end_effector=pose_from_matrix(
                self._data.site_xpos[self._ee_site_id], self._data.site_xmat[self._ee_site_id]
            ),
            base=pose_from_matrix(
                self._data.xpos[self._base_body_id], self._data.xmat[self._base_body_id]
            ),
            gripper_closed_fraction=gripper_closed,
            end_effector_velocity=self._site_velocity(),
        )

    def _site_velocity(self) -> npt.NDArray[np.float64]:
        rotational_linear = np.zeros(6)
        mujoco.mj_objectVelocity(
            self._model,
            self._data,
            mujoco.mjtObj.mjOBJ_SITE,
            self._ee_site_id,
            rotational_linear,
            0,
        )
        return np.concatenate([rotational_linear[3:], rotational_linear[:3]])

    def object_poses(self) -> dict[str, Pose]:
        return tasks.object_poses(self._env)

    def kinematics(self) -> KinematicModel:
        joint_ids = [self._model.joint(name).id for name in self._robot.robot_joints]
        return KinematicModel(
            mjcf_xml=self.mjcf_xml(),
            arm_joints=tuple(self._robot.robot_joints),
            end_effector_site=self._ee_site,
            joint_position_limits=self._model.jnt_range[joint_ids].copy(),
            joint_velocity_limits=np.full(len(joint_ids), self.config.max_joint_speed),
            state_index=tuple(1 + int(a) for a in self._model.jnt_qposadr[joint_ids]),
        )

    def mjcf_xml(self) -> str:
        """robosuite's model, with the bodies the last reset placed where it placed them."""
        positions, rotations = self.body_placements()
        loaded_positions, loaded_rotations = self._loaded_placements
        moved = np.flatnonzero(
            np.any(positions != loaded_positions, axis=1)
            | np.any(rotations != loaded_rotations, axis=1)
        )
        if moved.size == 0:
            return self._xml
        placements = {self._model.body(i).name: (positions[i], rotations[i]) for i in moved}
        return mjcf.with_body_placements(self._xml, placements)

    def body_placements(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """Every body's position and quaternion in its parent, as the last reset placed them:
        robosuite places fixtures (Door's door, PickPlace's visual stand-ins) in the model,
        not the state, so a copy of the model needs them to look the same."""
        return self._model.body_pos.copy(), self._model.body_quat.copy()

    def _load_fixed_model(self) -> None:
        """Recompile robosuite's model for our fast path.

        `self._xml` (what demonstrations save, what robosuite replays) is robosuite's model,
        with `model_fixes` if the config asks for them; the compiled physics model adds
        `fast_model`'s actuators to it.
        """
        pairs = (
            model_fixes.static_parent_pairs(self._env.sim.model._model)
            if self.config.exclude_base_contacts
            else []
        )
        robot = self._env.robots[0]
        parked = [obj.root_body for obj in tasks.hidden_objects(self._env)]

        def fix(xml: str) -> str:
            self._xml = model_fixes.add_contact_excludes(xml, pairs)
            if not self.fast_path:
                return self._xml
            return fast_model.fast_physics_xml(
                self._xml, robot.robot_model.root_body, robot.robot_joints, parked
            )

        self._env.set_xml_processor(fix)
        self._env.reset_from_xml_string(self._env.model.get_xml())

    # --- construction helpers --------------------------------------------------------------
    def _make_action_spec(self) -> ActionSpec:
        low, high = self._env.action_spec
        mode = self.config.action_mode
        return ActionSpec(mode, int(low.shape[0]), np.array(low), np.array(high))

    def _closed_fraction(self, data: mujoco.MjData) -> float:
        finger_q = data.qpos[self._gripper_qpos_index]
        closed = np.abs(finger_q - self._gripper_open_q) / self._gripper_span
        return float(np.clip(np.mean(closed), 0.0, 1.0))

    def _make_stepper(self) -> FastStepper | PlainStepper:
        if not self.fast_path:
            return PlainStepper(self._env)
        robot, arm = self._robot, self._arm
        layout = ArmLayout(
            qpos=self._arm_qpos_index,
            dofs=self._arm_qvel_index,
            motors=np.array(robot._ref_arm_joint_actuator_indexes),
            ee_site=self._ee_site_id,
        )
        return FastStepper(
            self._model,
            FoldedArm(self._model, layout),
            self._controller,
            self._base_body_id,
            np.array(robot._ref_joint_gripper_actuator_indexes[arm]),
            finger_direction(robot.gripper[arm]),
            self.control_dt,
            float(robot.gripper[arm].speed) if self.config.gripper_ramp else None,
        )

    def _init_gripper_geometry(self) -> None:
        """Finger joints: open is the gripper's initial pose, closed the far end of each range."""
        gripper = self._robot.gripper[self._arm]
        joint_ids = [self._model.joint(j).id for j in gripper.joints]
        self._gripper_qpos_index = self._model.jnt_qposadr[joint_ids]
        self._gripper_open_q = np.asarray(gripper.init_qpos, dtype=float)
        low, high = self._model.jnt_range[joint_ids].T
        far = np.where(high - self._gripper_open_q > self._gripper_open_q - low, high, low)
        self._gripper_span = np.maximum(np.abs(far - self._gripper_open_q), 1e-9)

    def _make_grasp_test(self) -> tasks.Grasped:
        """robosuite's grasp test (a contact between each finger pad and the object) on geom
        ids and numpy: robosuite's loops over the contacts in Python, name by name."""
        model, gripper = self._model, self._robot.gripper[self._arm]

        def mask(names: list[str]) -> npt.NDArray[np.bool_]:
            chosen = np.zeros(model.ngeom, dtype=bool)
            chosen[[model.geom(name).id for name in names]] = True
            return chosen

        pads = [
            mask(gripper.important_geoms[side]) for side in ("left_fingerpad", "right_fingerpad")
        ]
        objects = {obj.name: mask(obj.contact_geoms) for obj in tasks.active_objects(self._env)}

        def grasped(obj: Any) -> bool:  # a robosuite object (untyped)
            geoms = objects[obj.name]
            return all(touching(self._data, pad, geoms) for pad in pads)

        return grasped

    def _make_contact_reader(self) -> ContactReader:
        model = self._model
        robot_root = model.body(self._robot.robot_model.root_body).id
        prefixes = (self._robot.robot_model.naming_prefix, "gripper0_", "mount0_")
        robot_geoms = {}
        for geom in body_subtree_geoms(model, [robot_root]):
            name = model.body(model.geom_bodyid[geom]).name
            for prefix in prefixes:
                name = name.removeprefix(prefix)
            robot_geoms[geom] = name
        object_geoms = {
            geom: obj.name
            for obj in tasks.active_objects(self._env)
            for geom in body_subtree_geoms(model, [model.body(obj.root_body).id])
        }
        return ContactReader(model, robot_geoms, object_geoms)
