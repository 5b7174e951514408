"""Run one scripted episode through the full control path (operator -> teleoperator -> sim)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from crowdteleop.control.scripted.operator import ScriptedOperator
from crowdteleop.tasks import get_task

if TYPE_CHECKING:  # the teleoperator loads the controllers (MuJoCo); a network bot has none
    from crowdteleop.control.teleoperator import Teleoperator, TeleopStep

# robosuite's demonstration collector ends an episode after this many successful steps.
SUCCESS_HOLD_STEPS = 10


@dataclass(frozen=True)
class EpisodeResult:
    success: bool
    steps: int
    sim_seconds: float
    final_stage: str


def run_episode(
    teleop: Teleoperator,
    operator: ScriptedOperator,
    seed: int,
    time_limit_s: float | None = None,
    on_step: Callable[[TeleopStep], None] | None = None,
) -> EpisodeResult:
    """Reset with `seed`, drive until success has held `SUCCESS_HOLD_STEPS` steps or time runs
    out. `on_step` sees every step (to record, render or log it)."""
    teleop.reset(seed)
    operator.reset()
    dt = teleop.sim.control_dt
    limit = (
        time_limit_s if time_limit_s is not None else get_task(teleop.sim.config.task).time_limit_s
    )
    max_steps = round(limit / dt)
    held = 0
    for step_index in range(1, max_steps + 1):
        step = teleop.step(operator.command())
        if on_step is not None:
            on_step(step)
        held = held + 1 if step.result.success else 0
        if held >= SUCCESS_HOLD_STEPS:
            return EpisodeResult(True, step_index, step_index * dt, operator.stage)
    return EpisodeResult(False, max_steps, max_steps * dt, operator.stage)
