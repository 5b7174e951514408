"""Waypoints and the geometry plans use to build them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

from crowdteleop.sim.types import Pose


@dataclass(frozen=True)
class Waypoint:
    """Where the hand should go, with the gripper how, and how long to dwell once there."""

    pose: Pose
    gripper_closed: bool
    tolerance_m: float = 0.01
    dwell_s: float = 0.0
    timeout_s: float = 6.0
    label: str = ""
    # also there once the hand has been held up short of the mark this long (the command
    # there): a descent whose fingers meet the floor under an object, or nudge the object
    stall_s: float | None = None


def yaw_aligned(reference: Pose, axis_yaw: float, period: float) -> Rotation:
    """`reference`'s orientation turned about world z so its x axis (the fingers' closing axis)
    points along `axis_yaw`, modulo `period` (pi/2 for a cube, pi for a handle)."""
    x_axis = reference.rotation.apply([1.0, 0.0, 0.0])
    current = np.arctan2(x_axis[1], x_axis[0])
    turn = (axis_yaw - current + period / 2) % period - period / 2
    return Rotation.from_euler("z", turn) * reference.rotation


def yaw_of(pose: Pose) -> float:
    x_axis = pose.rotation.apply([1.0, 0.0, 0.0])
    return float(np.arctan2(x_axis[1], x_axis[0]))


def at(position: npt.ArrayLike, rotation: Rotation) -> Pose:
    return Pose(np.asarray(position, dtype=float), rotation.as_quat())
