"""Contact events for haptics and the quality metrics: which robot part touches which object
(or the table), and how hard."""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import mujoco
import numpy as np
import numpy.typing as npt

from crowdteleop.sim.types import ContactEvent
from crowdteleop.vocab import TABLE_CONTACT

# A normal force of this many newtons or more buzzes the phone at full intensity.
FULL_INTENSITY_NEWTONS = 20.0


def body_subtree_geoms(model: mujoco.MjModel, root_body_ids: Iterable[int]) -> set[int]:
    """Every geom on the given bodies or any of their descendants."""
    roots = set(root_body_ids)
    in_subtree = np.zeros(model.nbody, dtype=bool)
    for body_id in range(model.nbody):
        # Parents come before children in MuJoCo's body order, so one pass suffices.
        in_subtree[body_id] = body_id in roots or (
            body_id != 0 and in_subtree[model.body_parentid[body_id]]
        )
    return {g for g in range(model.ngeom) if in_subtree[model.geom_bodyid[g]]}


def table_geoms(
    model: mujoco.MjModel, robot_geoms: Iterable[int], object_geoms: Iterable[int]
) -> dict[int, str]:
    """The table (or bins) the objects stand on, each geom named `TABLE_CONTACT`: every geom
    that can collide on a body fixed to the world, other than the world's own (the floor) and
    the robot's and the objects'. Found by structure, not by name: robosuite's arenas name
    their tables and bins each their own way."""
    bodies = model.geom_bodyid
    fixed = (model.body_weldid[bodies] == 0) & (bodies != 0)
    collides = (model.geom_contype != 0) | (model.geom_conaffinity != 0)
    taken = set(robot_geoms) | set(object_geoms)
    return {int(g): TABLE_CONTACT for g in np.flatnonzero(fixed & collides) if g not in taken}


class ContactReader:
    """Turns MuJoCo's contact list into robot-part / object events; the table (`table_geoms`)
    is one of the objects, for every backend.

    Runs every control step, so the contact list is classified with numpy (geom -> part / object
    lookup tables) and only robot-object contacts cost a `mj_contactForce` call.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        robot_geoms: Mapping[int, str],
        object_geoms: Mapping[int, str],
    ) -> None:
        self._model = model
        object_geoms = {**object_geoms, **table_geoms(model, robot_geoms, object_geoms)}
        self._parts = sorted(set(robot_geoms.values()))
        self._objects = sorted(set(object_geoms.values()))
        self._part_of = np.full(model.ngeom, -1)
        for geom, part in robot_geoms.items():
            self._part_of[geom] = self._parts.index(part)
        self._object_of = np.full(model.ngeom, -1)
        for geom, obj in object_geoms.items():
            self._object_of[geom] = self._objects.index(obj)
        self._force = np.zeros(6)

    @property
    def objects(self) -> tuple[str, ...]:
        """The names its events can give the touched side."""
        return tuple(self._objects)

    def read(self, data: mujoco.MjData) -> list[ContactEvent]:
        if not data.ncon:
            return []
        geoms = data.contact.geom  # (ncon, 2)
        parts, objects = self._part_of[geoms], self._object_of[geoms]
        forward = (parts[:, 0] >= 0) & (objects[:, 1] >= 0)  # geom1 robot, geom2 object
        backward = ~forward & (parts[:, 1] >= 0) & (objects[:, 0] >= 0)
        strongest: dict[tuple[str, str], float] = {}
        for index in np.flatnonzero(forward | backward):
            robot_side = 0 if forward[index] else 1
            pair = (
                self._parts[parts[index, robot_side]],
                self._objects[objects[index, 1 - robot_side]],
            )
            mujoco.mj_contactForce(self._model, data, int(index), self._force)
            intensity = min(abs(self._force[0]) / FULL_INTENSITY_NEWTONS, 1.0)
            strongest[pair] = max(strongest.get(pair, 0.0), intensity)
        return [
            ContactEvent(part, obj, round(value, 4)) for (part, obj), value in strongest.items()
        ]


def touching(
    data: mujoco.MjData, geoms_1: npt.NDArray[np.bool_], geoms_2: npt.NDArray[np.bool_]
) -> bool:
    """Any contact between a geom of ``geoms_1`` and one of ``geoms_2`` (bool masks over the
    model's geoms), as robosuite's ``check_contact`` decides by name, without a Python loop."""
    if not data.ncon:
        return False
    pairs = data.contact.geom
    first, second = geoms_1[pairs], geoms_2[pairs]
    return bool(np.any((first[:, 0] & second[:, 1]) | (first[:, 1] & second[:, 0])))
