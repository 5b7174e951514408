"""robosuite's arm controllers evaluated once per control step and folded into MuJoCo actuators.

Both laws robosuite runs at every substep are, linearized at the start of the control step,
    tau(q, qdot) = tau0 - K (q - q_ref) - D qdot        (plus gravity, which MuJoCo compensates)
with symmetric K and D:
- JOINT_POSITION servo:  K = kp M, D = kd M, q_ref = q0 + qdot_cmd dt;
- OSC_POSE:              K = kp A + kn B, D = kd A + dn B, q_ref = q0, tau0 = J^T Lambda kp e0 + ...
  where A = J^T Lambda J and B = M - J^T Lambda_full J (robosuite's nullspace term N^T M = B).
`FoldedArm.apply` writes them into the tendon actuators of `fast_model`, so the 25 substeps
of a control step run in MuJoCo's C loop with no Python in between.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
import numpy.typing as npt
from robosuite.utils.control_utils import opspace_matrices, orientation_error

from crowdteleop.sim.robosuite_backend.fast_model import DAMPING_PREFIX, STIFFNESS_PREFIX

NULLSPACE_KP = 10.0  # robosuite's nullspace_torques default
NULLSPACE_KV = 2.0 * np.sqrt(NULLSPACE_KP)


@dataclass(frozen=True)
class ArmLayout:
    """Where the arm lives in the model's arrays."""

    qpos: npt.NDArray[np.intp]
    dofs: npt.NDArray[np.intp]
    motors: npt.NDArray[np.intp]
    ee_site: int


class FoldedArm:
    """Writes tau0, K, D, q_ref into the model's folded-controller actuators."""

    def __init__(self, model: mujoco.MjModel, layout: ArmLayout) -> None:
        self._model = model
        self.layout = layout
        n = len(layout.dofs)
        self._stiffness = self._actuators(STIFFNESS_PREFIX, n)
        self._damping = self._actuators(DAMPING_PREFIX, n)
        self._motor_low, self._motor_high = model.actuator_ctrlrange[layout.motors].T
        self._jacp = np.zeros((3, model.nv))
        self._jacr = np.zeros((3, model.nv))
        self._mass = np.zeros((model.nv, model.nv))

    def _actuators(
        self, prefix: str, count: int
    ) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
        """(actuator ids, (count, count) addresses in ``wrap_prm`` of their tendons' joint
        coefficients: row k holds tendon k's), so one indexed write sets every tendon."""
        model = self._model
        ids = np.array([model.actuator(f"{prefix}{k}").id for k in range(count)])
        tendons = [model.tendon(f"{prefix}{k}").id for k in range(count)]
        return ids, model.tendon_adr[tendons][:, None] + np.arange(count)[None, :]

    # --- the quantities robosuite's controllers read -----------------------------------
    def mass_matrix(self, data: mujoco.MjData) -> npt.NDArray[np.float64]:
        mujoco.mj_fullM(self._model, self._mass, data.qM)
        dofs = self.layout.dofs
        mass: npt.NDArray[np.float64] = self._mass[np.ix_(dofs, dofs)]
        return mass

    def jacobians(
        self, data: mujoco.MjData
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        mujoco.mj_jacSite(self._model, data, self._jacp, self._jacr, self.layout.ee_site)
        return self._jacp[:, self.layout.dofs], self._jacr[:, self.layout.dofs]

    def coriolis(self, data: mujoco.MjData) -> npt.NDArray[np.float64]:
        """Bias forces robosuite compensates that MuJoCo's gravcomp does not (Coriolis etc.)."""
        dofs = self.layout.dofs
        bias: npt.NDArray[np.float64] = data.qfrc_bias[dofs] - data.qfrc_gravcomp[dofs]
        return bias

    # --- the two laws ------------------------------------------------------------------
    def joint_servo(
        self, data: mujoco.MjData, goal: npt.NDArray[np.float64], kp: float, kd: float
    ) -> None:
        """K = kp M, D = kd M: one eigen-decomposition of M serves both."""
        gains, vectors = decompose(self.mass_matrix(data))
        self.apply(data, self.coriolis(data), (kp * gains, vectors), (kd * gains, vectors), goal)

    def osc(
        self,
        data: mujoco.MjData,
        goal_position: npt.NDArray[np.float64],
        goal_orientation: npt.NDArray[np.float64],
        initial_joints: npt.NDArray[np.float64],
        kp: float,
        kd: float,
    ) -> None:
        """robosuite's OSC_POSE (uncoupled position / orientation, nullspace posture term)."""
        q0 = data.qpos[self.layout.qpos]
        mass = self.mass_matrix(data)
        jac_pos, jac_ori = self.jacobians(data)
        jac = np.vstack([jac_pos, jac_ori])
        lambda_full, lambda_pos, lambda_ori, _ = opspace_matrices(mass, jac, jac_pos, jac_ori)
        site = self.layout.ee_site
        position_error = goal_position - data.site_xpos[site]
        orientation_err = orientation_error(goal_orientation, data.site_xmat[site].reshape(3, 3))
        wrench = np.concatenate(
            [lambda_pos @ (kp * position_error), lambda_ori @ (kp * orientation_err)]
        )
        task = jac_pos.T @ lambda_pos @ jac_pos + jac_ori.T @ lambda_ori @ jac_ori
        posture = mass - jac.T @ lambda_full @ jac
        tau0 = jac.T @ wrench + NULLSPACE_KP * posture @ (initial_joints - q0)
        stiffness = kp * task + NULLSPACE_KP * posture
        damping = kd * task + NULLSPACE_KV * posture
        self.apply(data, tau0 + self.coriolis(data), stiffness, damping, q0)

    # --- writing it into MuJoCo ----------------------------------------------------------
    def apply(
        self,
        data: mujoco.MjData,
        tau0: npt.NDArray[np.float64],
        stiffness: npt.NDArray[np.float64] | Basis,
        damping: npt.NDArray[np.float64] | Basis,
        q_ref: npt.NDArray[np.float64],
    ) -> None:
        """Write the law; K and D as symmetric matrices or already split (`decompose`)."""
        model = self._model
        data.ctrl[self.layout.motors] = np.clip(tau0, self._motor_low, self._motor_high)
        gains, vectors = decompose(stiffness) if isinstance(stiffness, np.ndarray) else stiffness
        actuators, coefficients = self._stiffness
        model.wrap_prm[coefficients] = vectors.T
        model.actuator_gainprm[actuators, 0] = gains
        model.actuator_biasprm[actuators, 1] = -gains
        data.ctrl[actuators] = vectors.T @ q_ref
        gains, vectors = decompose(damping) if isinstance(damping, np.ndarray) else damping
        actuators, coefficients = self._damping
        model.wrap_prm[coefficients] = vectors.T
        model.actuator_gainprm[actuators, 0] = gains
        model.actuator_biasprm[actuators, 2] = -gains


Basis = tuple[
    npt.NDArray[np.float64], npt.NDArray[np.float64]
]  # (gains >= 0, eigenvectors as columns)


def decompose(matrix: npt.NDArray[np.float64]) -> Basis:
    """K = sum_k gains_k v_k v_k^T for a symmetric K; negative (round-off) gains clipped."""
    gains, vectors = np.linalg.eigh(0.5 * (matrix + matrix.T))
    return np.maximum(gains, 0.0), vectors
