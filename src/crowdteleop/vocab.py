"""The platform's shared vocabularies: one definition each, imported by every process.

Plain `Literal` types, so pydantic validates them at every boundary, the JSON Schema the
browser reads lists their values, and the type checker catches a misspelt one.
"""

from __future__ import annotations

from typing import Literal, get_args

Outcome = Literal["success", "reset", "timeout", "disconnect", "crash"]
"""How an episode ended: held success, the worker's reset, the time limit, the controlling
device leaving, or a simulation failure."""
OUTCOMES: tuple[Outcome, ...] = get_args(Outcome)

WorkerDevice = Literal["phone", "keyboard", "vr", "spacemouse", "gamepad"]
"""What a person drives the robot with; a campaign offers some of them."""
WORKER_DEVICES: tuple[WorkerDevice, ...] = get_args(WorkerDevice)

DeviceKind = Literal[WorkerDevice, "bot"]
"""What sends device commands: a person's device, or a scripted bot."""
DEVICE_KINDS: tuple[DeviceKind, ...] = (*WORKER_DEVICES, "bot")

ClutchState = Literal[
    "no_driver", "released", "driving", "waiting_for_pose", "video_stalled", "press_again"
]
"""Whether the arm follows the driving device, and if not why (`teleop/clutch.py`): nobody
drives; the clutch is let go; it drives; pressed before the device sent a pose; the worker's
video stopped; the picture is back but the press is from before it stopped (let go, press)."""
CLUTCH_STATES: tuple[ClutchState, ...] = get_args(ClutchState)

SkillName = Literal["expert", "intermediate", "novice"]
"""How skilled a synthetic worker is (`crowdteleop bot --skill`): the scripted operator's
`OperatorStyle` for each level is `control.scripted.skills.SKILLS`."""
SKILL_NAMES: tuple[SkillName, ...] = get_args(SkillName)

ReviewDecision = Literal["accepted", "rejected"]
"""A reviewer's (or the campaign's automatic) verdict on a demonstration; an episode nobody
has decided, or whose decision was undone, has none."""
REVIEW_DECISIONS: tuple[ReviewDecision, ...] = get_args(ReviewDecision)

InjectedFault = Literal["idle", "detour", "drop", "press"]
"""A fault a synthetic worker can be told to make in each demonstration, to test that the
quality flags catch it (`control.scripted.skills.FAULTS`): a 10 s idle before the grasp, a
detour on the way to the object, the object dropped while carried, the hand pushed into the
table on its way down to the grasp."""
INJECTED_FAULTS: tuple[InjectedFault, ...] = get_args(InjectedFault)

TABLE_CONTACT = "table"
"""The object a contact event names when the arm touches the table (or the bins) the task's
objects stand on: the phone buzzes, and the quality metrics count the touches (pressing into
the table strains the arm and shoves the objects; a policy learns to scrape)."""

ControllerName = Literal["ik-velocity", "osc"]
"""The control law turning a desired end-effector pose into simulation actions."""
CONTROLLERS: tuple[ControllerName, ...] = get_args(ControllerName)

ActionMode = Literal["joint-velocity", "osc-pose"]
"""The action space a simulation accepts."""

ACTION_MODE_FOR_CONTROLLER: dict[ControllerName, ActionMode] = {
    "ik-velocity": "joint-velocity",
    "osc": "osc-pose",
}


def action_mode_for(controller: ControllerName) -> ActionMode:
    """The simulation action mode `controller` drives: derived, never configured twice."""
    return ACTION_MODE_FOR_CONTROLLER[controller]
