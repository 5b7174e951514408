"""Whether the fast path can serve a robosuite task it has never seen.

The fast path replaces robosuite's step: it folds the arm's controller into MuJoCo actuators
and steps the substeps in C (`fast_step`). That is faithful for any single-arm task whose
environment leaves the step to robosuite's base classes. A task that runs its own code in the
step (``_pre_action``, ``_post_action``, ``step``) would lose it; such a task gets robosuite's
own path, with a warning saying why.
"""

from __future__ import annotations

from typing import Any

STEP_HOOKS = ("step", "_pre_action", "_post_action")
ROBOSUITE_BASES = ("robosuite.environments.base", "robosuite.environments.robot_env")


def fast_path_obstacles(env: Any) -> list[str]:
    """Why the fast path would change what this environment does; empty when it would not."""
    obstacles = []
    for hook in STEP_HOOKS:
        owner = next(cls for cls in type(env).__mro__ if hook in vars(cls))
        if owner.__module__ not in ROBOSUITE_BASES:
            obstacles.append(
                f"{type(env).__name__} runs its own {hook} ({owner.__module__}.{owner.__name__}), "
                "which the fast path's C stepping would skip"
            )
    if len(env.robots) != 1:
        obstacles.append(f"{len(env.robots)} robots: the fast path folds one arm")
    elif len(env.robots[0].arms) != 1:
        obstacles.append("a robot with several arms: the fast path folds one arm")
    return obstacles
