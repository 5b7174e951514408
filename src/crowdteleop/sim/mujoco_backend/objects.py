"""The objects of a plain-MuJoCo task: lift's cube, or a plug-in's own bodies (docs/tasks.md).

Each top-level body the task brings is an object: placed at reset (a free body anywhere within
`XY_RANGE` of where its MJCF puts it, turned at random about z), posed for scripted operators,
in the ``object`` observation, touched for haptics, held when both finger pads touch it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
import numpy.typing as npt

from crowdteleop.sim.contacts import body_subtree_geoms
from crowdteleop.sim.mujoco_data import pose_from_matrix
from crowdteleop.sim.types import Pose

XY_RANGE = 0.08  # m, uniform around each free object's MJCF position


@dataclass(frozen=True)
class MujocoScene:
    """What a plain-MuJoCo task's own success and stage functions are given."""

    model: mujoco.MjModel
    data: mujoco.MjData

    def position(self, body: str) -> npt.NDArray[np.float64]:
        """A body's world position (m)."""
        return np.array(self.data.body(body).xpos)


@dataclass(frozen=True)
class SceneObject:
    name: str
    body: int
    qpos: int | None  # the free joint's first qpos; None: the object does not move
    home: npt.NDArray[np.float64]  # where the MJCF puts it
    geoms: npt.NDArray[np.bool_]  # its subtree's geoms, as a mask over the model's


class SceneObjects:
    """The task's objects in one model."""

    def __init__(self, model: mujoco.MjModel, names: Sequence[str]) -> None:
        self.items = [self._describe(model, name) for name in names]

    @staticmethod
    def _describe(model: mujoco.MjModel, name: str) -> SceneObject:
        body = model.body(name).id
        free = [
            j
            for j in range(model.njnt)
            if model.jnt_bodyid[j] == body and model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE
        ]
        geoms = np.zeros(model.ngeom, dtype=bool)
        geoms[sorted(body_subtree_geoms(model, [body]))] = True
        qpos = int(model.jnt_qposadr[free[0]]) if free else None
        return SceneObject(name, body, qpos, model.body_pos[body].copy(), geoms)

    def place(self, data: mujoco.MjData, rng: np.random.Generator) -> None:
        """Each free object somewhere near its home, turned about z."""
        for item in self.items:
            if item.qpos is None:
                continue
            x, y = rng.uniform(-XY_RANGE, XY_RANGE, size=2)
            yaw = rng.uniform(-np.pi, np.pi)
            position = item.home + [x, y, 0.0]
            rotation = (np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2))
            data.qpos[item.qpos : item.qpos + 7] = (*position, *rotation)

    def poses(self, data: mujoco.MjData) -> dict[str, Pose]:
        return {
            item.name: pose_from_matrix(data.xpos[item.body], data.xmat[item.body])
            for item in self.items
        }

    def observation(
        self, data: mujoco.MjData, hand: npt.NDArray[np.float64]
    ) -> npt.NDArray[np.float64]:
        """robosuite's ``object`` key: per object position, quaternion (x, y, z, w), position
        minus the hand's."""
        parts = []
        for item in self.items:
            if item.qpos is not None:
                pose = data.qpos[item.qpos : item.qpos + 7]
                position, wxyz = pose[:3], pose[3:]
            else:
                position, wxyz = data.xpos[item.body], data.xquat[item.body]
            xyzw = np.array([wxyz[1], wxyz[2], wxyz[3], wxyz[0]])
            parts.append(np.concatenate([position, xyzw, position - hand]))
        return np.concatenate(parts)

    def held(self, data: mujoco.MjData, pads: Sequence[int]) -> list[str]:
        """The objects both finger pads touch."""
        contact = data.contact
        held = []
        for item in self.items:
            touching = np.concatenate(
                (contact.geom2[item.geoms[contact.geom1]], contact.geom1[item.geoms[contact.geom2]])
            )
            if all(pad in touching for pad in pads):
                held.append(item.name)
        return held

    def contact_names(self, model: mujoco.MjModel) -> dict[int, str]:
        """Geom id -> object name, for haptic contact events."""
        return {int(geom): item.name for item in self.items for geom in np.flatnonzero(item.geoms)}
