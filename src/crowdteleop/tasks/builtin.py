"""The tasks crowdteleop ships: the paper's (lift, pick-place, nut-assembly and their one-object
variants) and more of robosuite's, on robosuite's own classes."""

from __future__ import annotations

from crowdteleop.tasks.spec import Stage, TaskSpec

_STAGES = "crowdteleop.sim.robosuite_backend.stages"

BUILTIN_TASKS: tuple[TaskSpec, ...] = (
    TaskSpec(
        "lift",
        "robosuite",
        "Lift",
        "Pick up the red cube and lift it above the table.",
        time_limit_s=60.0,
        symmetric_objects={"cube": 4},
    ),
    TaskSpec(
        "pick-place",
        "robosuite",
        "PickPlace",
        "Put the milk, bread, cereal and can each into its own bin.",
        time_limit_s=300.0,
        symmetric_objects={"Can": 0},
    ),
    TaskSpec(
        "pick-place-can",
        "robosuite",
        "PickPlaceCan",
        "Pick up the can and place it into its bin (bottom right).",
        symmetric_objects={"Can": 0},
    ),
    TaskSpec(
        "pick-place-milk",
        "robosuite",
        "PickPlaceMilk",
        "Pick up the milk carton and place it into its bin (top left).",
    ),
    TaskSpec(
        "pick-place-bread",
        "robosuite",
        "PickPlaceBread",
        "Pick up the bread and place it into its bin (top right).",
    ),
    TaskSpec(
        "pick-place-cereal",
        "robosuite",
        "PickPlaceCereal",
        "Pick up the cereal box and place it into its bin (bottom left).",
    ),
    TaskSpec(
        "nut-assembly",
        "robosuite",
        "NutAssembly",
        "Fit the square nut onto the square peg and the round nut onto the round peg.",
        time_limit_s=300.0,
    ),
    TaskSpec(
        "nut-assembly-round",
        "robosuite",
        "NutAssemblyRound",
        "Fit the round nut onto the round peg.",
    ),
    TaskSpec(
        "nut-assembly-square",
        "robosuite",
        "NutAssemblySquare",
        "Fit the square nut onto the square peg.",
    ),
    TaskSpec(
        "stack",
        "robosuite",
        "Stack",
        "Stack the red cube on the green cube.",
        time_limit_s=90.0,
        symmetric_objects={"cubeA": 4, "cubeB": 4},
        stages=(
            Stage(
                "reach",
                "Reach for the red cube and grasp it.",
                f"{_STAGES}:holds_cube_a",
                relative_to="cubeA",
            ),
            Stage(
                "stack",
                "Red cube grasped: put it on the green cube.",
                f"{_STAGES}:stacked",
                relative_to="cubeB",
            ),
        ),
    ),
    TaskSpec(
        "door",
        "robosuite",
        "Door",
        "Turn the door's handle down and pull the door open.",
        time_limit_s=90.0,
        stages=(
            Stage("reach", "Reach for the door's handle and grasp it.", f"{_STAGES}:holds_handle"),
            Stage(
                "open",
                "Handle grasped: turn it down and pull the door open.",
                f"{_STAGES}:door_open",
            ),
        ),
    ),
    TaskSpec(
        "mujoco-lift",
        "mujoco",
        "lift",
        "Pick up the red cube and lift it above the table (pure-MuJoCo scene, no robosuite).",
        time_limit_s=60.0,
    ),
)
