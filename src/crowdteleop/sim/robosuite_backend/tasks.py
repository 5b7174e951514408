"""What each robosuite task means for the UI and for scripted operators.

robosuite keeps task knowledge in private attributes of each environment class; this module is
the one place that reads them, so the rest of the platform never does.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np

from crowdteleop.sim.mujoco_data import pose_from_matrix
from crowdteleop.sim.types import Pose, TaskProgress


def _all_objects(env: Any) -> list[Any]:
    """The task's objects: robosuite's own lists where it keeps them (PickPlace's also hold
    visual stand-ins), else every object of the task's model that is not visual only."""
    if hasattr(env, "cube"):
        return [env.cube]
    known = getattr(env, "nuts", None) or getattr(env, "objects", None)
    if known:
        return list(known)
    return [obj for obj in env.model.mujoco_objects if getattr(obj, "obj_type", "all") != "visual"]


def active_objects(env: Any) -> list[Any]:
    """The robosuite objects the episode is about (single-object variants hide the rest)."""
    objects = _all_objects(env)
    if getattr(env, "single_object_mode", 0) in (1, 2):
        objects = [obj for obj in objects if obj.name == env.obj_to_use]
    return objects


def hidden_objects(env: Any) -> list[Any]:
    """Objects robosuite parks off the table in single-object variants (PickPlaceCan, ...)."""
    active = active_objects(env)
    return [obj for obj in _all_objects(env) if obj not in active]


def _body_pose(env: Any, body_name: str) -> Pose:
    body_id = env.sim.model.body_name2id(body_name)
    return pose_from_matrix(env.sim.data.body_xpos[body_id], env.sim.data.body_xmat[body_id])


def _site_pose(env: Any, site_name: str) -> Pose:
    site_id = env.sim.model.site_name2id(site_name)
    return pose_from_matrix(env.sim.data.site_xpos[site_id], env.sim.data.site_xmat[site_id])


def object_poses(env: Any) -> dict[str, Pose]:
    """Object poses, plus "<name>/handle" grasp frames and "<name>/target" goal positions."""
    poses: dict[str, Pose] = {}
    identity = np.array([0.0, 0.0, 0.0, 1.0])
    active = active_objects(env)
    for index, obj in enumerate(_all_objects(env)):
        if obj not in active:
            continue
        poses[obj.name] = _body_pose(env, obj.root_body)
        if "handle" in obj.important_sites:
            poses[f"{obj.name}/handle"] = _site_pose(env, obj.important_sites["handle"])
        if hasattr(env, "target_bin_placements"):
            poses[f"{obj.name}/target"] = Pose(np.array(env.target_bin_placements[index]), identity)
        if hasattr(env, "peg1_body_id"):
            peg = env.peg1_body_id if "square" in obj.name.lower() else env.peg2_body_id
            poses[f"{obj.name}/target"] = Pose(np.array(env.sim.data.body_xpos[peg]), identity)
    if hasattr(env, "table_offset"):
        poses["table"] = Pose(np.array(env.table_offset), identity)
    return poses


Grasped = Callable[[Any], bool]  # robosuite object -> whether the gripper holds it


def robosuite_grasped(env: Any) -> Grasped:
    """robosuite's own grasp test (both finger pads touch the object), by geom names."""

    def grasped(obj: Any) -> bool:
        gripper = env.robots[0].gripper
        return bool(env._check_grasp(gripper=gripper, object_geoms=obj.contact_geoms))

    return grasped


@contextmanager
def success_checked_once(env: Any) -> Iterator[None]:
    """Inside, robosuite's ``_check_success`` runs at most once and later calls get its answer.

    One control step asks three times for the same state (the reward, `success`, `progress`);
    for PickPlace and NutAssembly each is a loop over objects. Its side effect (robosuite
    refreshes ``objects_in_bins`` / ``objects_on_pegs``) happens on the first call.
    """
    original = env._check_success
    answers: list[Any] = []

    def once() -> Any:
        if not answers:
            answers.append(original())
        return answers[0]

    env._check_success = once  # an instance attribute shadows the method
    try:
        yield
    finally:
        del env._check_success


def has_own_progress(env: Any) -> bool:
    """Whether `progress` knows this environment's sub-goals (Lift, PickPlace, NutAssembly)."""
    return (
        hasattr(env, "cube") or hasattr(env, "objects_in_bins") or hasattr(env, "objects_on_pegs")
    )


def progress(env: Any, success: bool, grasped: Grasped | None = None) -> TaskProgress:
    """A stage and a sentence for the worker, e.g. "can grasped" or "1 of 2 nuts placed".

    ``grasped`` answers robosuite's grasp test (default: robosuite's own, by geom names).
    """
    grasped = grasped or robosuite_grasped(env)
    objects = active_objects(env)
    if hasattr(env, "cube"):
        if success:
            return TaskProgress("done", "Cube lifted: well done!", 2, 2)
        cube = env.cube.name
        if grasped(env.cube):
            return TaskProgress("grasped", "Cube grasped: now lift it.", 1, 2, cube)
        return TaskProgress("reach", "Reach for the cube and grasp it.", 0, 2, cube)

    env._check_success()  # refreshes objects_in_bins / objects_on_pegs
    placed_flags = getattr(env, "objects_in_bins", None)
    if placed_flags is None:
        placed_flags = env.objects_on_pegs
    all_objects = _all_objects(env)
    placed = sum(int(placed_flags[all_objects.index(obj)]) for obj in objects)
    noun = "nuts" if hasattr(env, "nuts") else "objects"
    where = "on their pegs" if hasattr(env, "nuts") else "in their bins"
    if success:
        return TaskProgress("done", f"All {noun} {where}: well done!", placed, len(objects))
    held = [obj.name for obj in objects if grasped(obj)]
    if held:
        return TaskProgress(
            "grasped",
            f"{held[0]} grasped; {placed} of {len(objects)} {noun} {where}.",
            placed,
            len(objects),
            f"{held[0]}/target",
        )
    waiting = [obj.name for obj in objects if not placed_flags[all_objects.index(obj)]]
    return TaskProgress(
        "reach",
        f"{placed} of {len(objects)} {noun} {where}.",
        placed,
        len(objects),
        waiting[0] if waiting else "",
    )
