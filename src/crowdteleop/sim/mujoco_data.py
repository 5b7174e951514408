"""Plain data read off MuJoCo's arrays, for the backends: poses from its rotation matrices and
the flat [time, qpos, qvel] state. Kept apart from `crowdteleop.sim.types` so the types load
without MuJoCo."""

from __future__ import annotations

import mujoco
import numpy as np
import numpy.typing as npt

from crowdteleop.sim.types import Pose

_STATE = mujoco.mjtState
FLAT_STATE = _STATE.mjSTATE_TIME | _STATE.mjSTATE_QPOS | _STATE.mjSTATE_QVEL


def pose_from_matrix(
    position: npt.NDArray[np.float64], rotation_matrix: npt.NDArray[np.float64]
) -> Pose:
    """A pose from a position and a 3x3 (or flat 9) rotation matrix, as MuJoCo stores them.

    MuJoCo's own conversion: 20x cheaper than scipy's, and it runs every control step.
    """
    wxyz = np.empty(4)
    mujoco.mju_mat2Quat(wxyz, np.asarray(rotation_matrix, dtype=float).reshape(9))
    return Pose(np.array(position, dtype=float), wxyz[[1, 2, 3, 0]])


def flat_state(model: mujoco.MjModel, data: mujoco.MjData) -> npt.NDArray[np.float64]:
    """A new [time, qpos, qvel] vector (robosuite's flattened layout, MuJoCo's own state order),
    filled by one ``mj_getState`` call: the teleop server takes one every control step."""
    state = np.empty(1 + model.nq + model.nv)
    mujoco.mj_getState(model, data, state, FLAT_STATE)
    return state
