"""Which of a dataset's action arrays a policy learns, and the form it learns them in.

- ``actions``: the recorded delta actions, as they are.
- ``actions_abs``: the absolute end-effector targets (``[x, y, z, ax, ay, az, gripper]``, the
  layout of `crowdteleop.dataset.absolute`). Their axis-angle rotation jumps where the angle
  passes pi (a hand pointing down sits right there: ``+pi x`` and ``-pi x`` are one pose), which
  a regression head cannot follow, so the policy learns the rotation as the first two columns
  of its matrix (the continuous "6D" form robomimic's diffusion policy trains absolute actions
  in) and turns them back into axis-angle when it acts.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

ActionKey = Literal["actions", "actions_abs"]
ACTION_KEYS: tuple[ActionKey, ...] = ("actions", "actions_abs")

Array = npt.NDArray[np.float64]


def to_learned(actions: Array, key: ActionKey) -> Array:
    """(N, A) recorded rows in the form the policy learns: ``actions_abs`` (N, 7) -> (N, 10)."""
    if key == "actions":
        return actions
    six = six_d(Rotation.from_rotvec(actions[:, 3:6]).as_matrix())
    return np.concatenate([actions[:, :3], six, actions[:, 6:]], axis=1)


def six_d(matrices: Array) -> Array:
    """(N, 3, 3) rotation matrices -> (N, 6): the first column, then the second."""
    return matrices[:, :, :2].transpose(0, 2, 1).reshape(len(matrices), 6)


def from_learned(row: Array, key: ActionKey) -> Array:
    """One policy output back in the recorded layout (Gram-Schmidt on the two columns)."""
    if key == "actions":
        return row
    first, second = row[3:6], row[6:9]
    x = first / max(float(np.linalg.norm(first)), 1e-9)
    y = second - x * float(x @ second)
    y = y / max(float(np.linalg.norm(y)), 1e-9)
    matrix = np.stack([x, y, np.cross(x, y)], axis=1)
    rotvec = Rotation.from_matrix(matrix).as_rotvec()
    return np.concatenate([row[:3], rotvec, row[9:]])
