"""Scripted operators: the platform's test users. They read privileged state and send the same
device commands a person's phone would (clutch, pose, gripper), with optional human-like noise,
hesitation and speed."""

from crowdteleop.control.scripted.episode import EpisodeResult, run_episode
from crowdteleop.control.scripted.operator import OperatorStyle, ScriptedOperator
from crowdteleop.control.scripted.plans import PLANS, plan_for

__all__ = [
    "PLANS",
    "EpisodeResult",
    "OperatorStyle",
    "ScriptedOperator",
    "plan_for",
    "run_episode",
]
