"""Plain data that crosses the `Simulation` boundary. Quaternions are (x, y, z, w) everywhere.

numpy only: a client that merely reads poses (the network bot) loads no simulator. What reads
these off MuJoCo's arrays is `crowdteleop.sim.mujoco_data`; rotation maths is scipy's, loaded
by the first `Pose.rotation`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from crowdteleop.errors import InvalidActionError, InvalidStateError

if TYPE_CHECKING:
    from scipy.spatial.transform import Rotation


@dataclass(frozen=True)
class Pose:
    """A rigid pose: position in metres and unit quaternion (x, y, z, w)."""

    position: npt.NDArray[np.float64]
    quaternion: npt.NDArray[np.float64]

    @property
    def rotation(self) -> Rotation:
        """The orientation as scipy's `Rotation`, for composing and comparing poses."""
        from scipy.spatial.transform import Rotation  # the controllers' maths, not the data's

        return Rotation.from_quat(self.quaternion)


@dataclass(frozen=True)
class Marker:
    """A sphere drawn into rendered frames only: no body, no collision, not in the state, so
    showing one changes neither the physics nor what an episode records."""

    position_m: tuple[float, float, float]  # world frame
    radius_m: float
    rgba: tuple[float, float, float, float]  # alpha < 1 is see-through


@dataclass(frozen=True)
class ContactEvent:
    """A robot part touching an object, for haptic feedback. Intensity is normalized to [0, 1]."""

    robot_part: str
    object: str
    intensity: float


@dataclass(frozen=True)
class TaskProgress:
    """What the UI shows the worker: a stage name, a sentence, and done / total sub-goals.

    ``relative_to`` names the object (a key of `Simulation.object_poses`) the stage's motion is
    relative to ("cube" while reaching for it, "Can/target" while carrying the can to its bin):
    the subtask labels that demonstration generation segments by. Empty: none (done)."""

    stage: str
    message: str
    completed: int
    total: int
    relative_to: str = ""


@dataclass(frozen=True)
class RobotState:
    """Proprioception the controllers need: arm joints, end-effector and base poses, gripper."""

    joint_positions: npt.NDArray[np.float64]
    joint_velocities: npt.NDArray[np.float64]
    end_effector: Pose
    base: Pose
    gripper_closed_fraction: float
    end_effector_velocity: npt.NDArray[np.float64] = field(default_factory=lambda: np.zeros(6))
    """(vx, vy, vz, wx, wy, wz) in the world frame, m/s and rad/s."""


@dataclass(frozen=True)
class KinematicModel:
    """What an IK solver needs to build its own copy of the robot's kinematics."""

    mjcf_xml: str
    arm_joints: tuple[str, ...]
    end_effector_site: str
    joint_position_limits: npt.NDArray[np.float64]  # (n, 2) radians
    joint_velocity_limits: npt.NDArray[np.float64]  # (n,) rad/s, symmetric
    # where each arm joint's position sits in `Simulation.get_state()` ([time, qpos, qvel])
    state_index: tuple[int, ...] = ()


@dataclass(frozen=True)
class ActionSpec:
    """The action vector `Simulation.step` takes: `mode` decides its meaning.

    - ``joint-velocity``: arm joint velocities in rad/s (clipped to the limits), then gripper.
    - ``osc-pose``: robosuite OSC_POSE delta (dx, dy, dz, ax, ay, az) in [-1, 1], then gripper.
    The last entry is always the gripper: -1 open, +1 closed.
    """

    mode: str
    size: int
    low: npt.NDArray[np.float64]
    high: npt.NDArray[np.float64]

    def validate(self, action: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """The action as floats clipped to the bounds; wrong shape or NaN / inf is refused."""
        action = np.asarray(action, dtype=float)
        if action.shape != (self.size,):
            raise InvalidActionError(
                f"action must have shape ({self.size},) for {self.mode}, got {action.shape}"
            )
        if not np.all(np.isfinite(action)):
            raise InvalidActionError("action contains NaN or infinity")
        return np.clip(action, self.low, self.high)


def validate_state(state: npt.NDArray[np.float64], size: int) -> npt.NDArray[np.float64]:
    """A flat [time, qpos, qvel] vector of the expected size, finite, as floats."""
    state = np.asarray(state, dtype=float)
    if state.shape != (size,):
        raise InvalidStateError(f"state must have shape ({size},), got {state.shape}")
    if not np.all(np.isfinite(state)):
        raise InvalidStateError("state contains NaN or infinity")
    return state


@dataclass(frozen=True)
class StepResult:
    reward: float
    success: bool
    contacts: list[ContactEvent] = field(default_factory=list)
    progress: TaskProgress | None = None


def low_dim_keys(
    observables: Mapping[str, Any], robot_prefix: str = "robot0_"
) -> dict[str, npt.NDArray[np.float64]]:
    """robosuite's observables renamed as robomimic's environment wrapper does: ``object``
    (robosuite's ``object-state``) and every ``robot0_*`` key except the concatenated
    ``proprio-state``; images are left out. robomimic's stock configs ask for these keys."""
    keys: dict[str, npt.NDArray[np.float64]] = {}
    if "object-state" in observables:
        keys["object"] = np.array(observables["object-state"], dtype=np.float64)
    for key, value in observables.items():
        array = np.asarray(value)
        if key.startswith(robot_prefix) and not key.endswith("proprio-state") and array.ndim < 2:
            keys[key] = np.array(array, dtype=np.float64).reshape(-1)
    return keys
