"""Poses as 4x4 homogeneous matrices, the form MimicGen's transforms are written in.

A recorded pose is ``[x, y, z, qx, qy, qz, qw]`` (metres, scipy's quaternion order, as
`crowdteleop.sim.types.Pose`); an absolute OSC target is ``[x, y, z, ax, ay, az]`` (axis-angle)
in the arm base's frame (`crowdteleop.dataset.absolute`).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation, Slerp

Matrix = npt.NDArray[np.float64]  # (4, 4) or (N, 4, 4)


def from_pose7(poses: npt.NDArray[np.float64]) -> Matrix:
    """(..., 7) position + quaternion (x, y, z, w) -> (..., 4, 4)."""
    poses = np.asarray(poses, dtype=np.float64)
    flat = poses.reshape(-1, 7)
    out = np.tile(np.eye(4), (len(flat), 1, 1))
    out[:, :3, :3] = Rotation.from_quat(flat[:, 3:]).as_matrix()
    out[:, :3, 3] = flat[:, :3]
    return out.reshape(*poses.shape[:-1], 4, 4)


def from_target(targets: npt.NDArray[np.float64]) -> Matrix:
    """(..., 6+) absolute targets (position, axis-angle) -> (..., 4, 4)."""
    targets = np.asarray(targets, dtype=np.float64)
    flat = targets.reshape(-1, targets.shape[-1])
    out = np.tile(np.eye(4), (len(flat), 1, 1))
    out[:, :3, :3] = Rotation.from_rotvec(flat[:, 3:6]).as_matrix()
    out[:, :3, 3] = flat[:, :3]
    return out.reshape(*targets.shape[:-1], 4, 4)


def to_target(matrix: Matrix) -> npt.NDArray[np.float64]:
    """(4, 4) -> (6,) position and axis-angle."""
    return np.concatenate([matrix[:3, 3], Rotation.from_matrix(matrix[:3, :3]).as_rotvec()])


def inverse(matrix: Matrix) -> Matrix:
    """The inverse of a rigid transform."""
    out = np.eye(4)
    out[:3, :3] = matrix[:3, :3].T
    out[:3, 3] = -matrix[:3, :3].T @ matrix[:3, 3]
    return out


def moved_with(poses: Matrix, old_frame: Matrix, new_frame: Matrix) -> Matrix:
    """(N, 4, 4) poses that kept their relation to an object frame now at ``new_frame``:
    MimicGen's ``T' = O' O^-1 T``."""
    return np.asarray(new_frame @ inverse(old_frame) @ poses)


def rotation_angle(a: Matrix, b: Matrix) -> float:
    """The angle (rad) of the rotation between two poses' orientations."""
    relative = a[:3, :3].T @ b[:3, :3]
    return float(math.acos(np.clip((np.trace(relative) - 1.0) / 2.0, -1.0, 1.0)))


def distance(a: Matrix, b: Matrix, rotation_weight_m: float) -> float:
    """Position distance plus ``rotation_weight_m`` metres per radian of rotation."""
    return float(np.linalg.norm(a[:3, 3] - b[:3, 3])) + rotation_weight_m * rotation_angle(a, b)


def interpolate(start: Matrix, end: Matrix, steps: int) -> Matrix:
    """(steps, 4, 4) poses from just after ``start`` to ``end``: linear in position, slerp in
    orientation."""
    fractions = np.arange(1, steps + 1) / steps
    slerp = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([start[:3, :3], end[:3, :3]])))
    out = np.tile(np.eye(4), (steps, 1, 1))
    out[:, :3, :3] = slerp(fractions).as_matrix()
    out[:, :3, 3] = start[:3, 3] + fractions[:, None] * (end[:3, 3] - start[:3, 3])
    return out


def nearest_symmetric(frame: Matrix, reference: Matrix, fold: int) -> Matrix:
    """``frame`` turned about its own z axis by the symmetry of its object that brings it
    nearest ``reference``: ``fold`` turns make a full one (4: a cube), 0 any turn (a cylinder),
    1 none. A grasp moved with a symmetric object then keeps the hand's orientation instead of
    spinning it by a turn that changes nothing."""
    if fold == 1:
        return frame
    local = frame[:3, :3].T @ reference[:3, :3]
    turn = math.atan2(local[1, 0], local[0, 0])
    if fold > 1:
        step = 2 * math.pi / fold
        turn = round(turn / step) * step
    out = frame.copy()
    out[:3, :3] = frame[:3, :3] @ Rotation.from_euler("z", turn).as_matrix()
    return out
