"""Stage tests of the built-in tasks that declare stages: ``f(env) -> bool`` on a robosuite
environment, named in `crowdteleop.tasks.builtin` as a plug-in would name its own."""

from __future__ import annotations

from typing import Any

DOOR_OPEN_RAD = 0.3  # robosuite's Door succeeds when its hinge turns past this


def _holds(env: Any, obj: Any) -> bool:
    return bool(env._check_grasp(gripper=env.robots[0].gripper, object_geoms=obj))


def holds_cube_a(env: Any) -> bool:
    """The gripper holds Stack's red cube (cubeA)."""
    return _holds(env, env.cubeA)


def stacked(env: Any) -> bool:
    """robosuite's Stack success: cubeA rests on cubeB and the gripper let go."""
    return bool(env._check_success())


def holds_handle(env: Any) -> bool:
    """Both finger pads touch the door's handle."""
    return _holds(env, [f"{env.door.naming_prefix}handle"])


def door_open(env: Any) -> bool:
    """robosuite's Door success: the hinge turned past 0.3 rad."""
    return bool(env._check_success())
