"""Contact events for haptics: which robot part touches which object, and how hard."""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import mujoco
import numpy as np

from crowdteleop.sim.types import ContactEvent

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


class ContactReader:
    """Turns MuJoCo's contact list into robot-part / object events."""

    def __init__(
        self,
        model: mujoco.MjModel,
        robot_geoms: Mapping[int, str],
        object_geoms: Mapping[int, str],
    ) -> None:
        self._model = model
        self._robot_geoms = dict(robot_geoms)
        self._object_geoms = dict(object_geoms)
        self._force = np.zeros(6)

    def read(self, data: mujoco.MjData) -> list[ContactEvent]:
        strongest: dict[tuple[str, str], float] = {}
        for index in range(data.ncon):
            contact = data.contact[index]
            pair = self._classify(contact.geom1, contact.geom2)
            if pair is None:
                continue
            mujoco.mj_contactForce(self._model, data, index, self._force)
            intensity = min(abs(self._force[0]) / FULL_INTENSITY_NEWTONS, 1.0)
            strongest[pair] = max(strongest.get(pair, 0.0), intensity)
        return [
            ContactEvent(part, obj, round(value, 4)) for (part, obj), value in strongest.items()
        ]

    def _classify(self, geom1: int, geom2: int) -> tuple[str, str] | None:
        for robot_geom, other in ((geom1, geom2), (geom2, geom1)):
            part = self._robot_geoms.get(robot_geom)
            obj = self._object_geoms.get(other)
            if part is not None and obj is not None:
                return part, obj
        return None
