"""A task's own success and stage functions (`TaskSpec.success`, `TaskSpec.stages`), on either
backend: each is called with the backend's subject (robosuite's environment, or a
`MujocoScene`).

A declared function runs on every control step inside the session; one that raises must not end
the session or lose its recording. Its answer counts as "not yet", the failure is counted in
`errors` and logged once per function.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from crowdteleop.sim.types import TaskProgress
from crowdteleop.tasks import Stage, TaskSpec, resolve

logger = logging.getLogger(__name__)

Check = Callable[[Any], Any]  # the backend's subject -> truthy when done
DONE = "Task done: well done!"


class DeclaredChecks:
    """The task's declared functions, resolved once, asked safely."""

    def __init__(self, task: TaskSpec, subject: Any) -> None:
        self._task = task
        self._subject = subject
        self._success: Check | None = resolve(task.success) if task.success else None
        self._stages: list[tuple[Stage, Check]] = [
            (stage, resolve(stage.done_when)) for stage in task.stages
        ]
        self.errors = 0
        self._logged: set[str] = set()

    @property
    def declares_success(self) -> bool:
        return self._success is not None

    @property
    def declares_stages(self) -> bool:
        return bool(self._stages)

    def _ask(self, check: Check, reference: str) -> bool:
        try:
            return bool(check(self._subject))
        except Exception as error:  # a plug-in's code may raise anything
            self.errors += 1
            if reference not in self._logged:
                self._logged.add(reference)
                logger.warning(
                    "task %r: %s raised %s: %s (counted as not yet done; further errors "
                    "are counted, not logged)",
                    self._task.name,
                    reference,
                    type(error).__name__,
                    error,
                )
            return False

    def success(self) -> bool:
        assert self._success is not None and self._task.success is not None
        return self._ask(self._success, self._task.success)

    def staged_progress(self, success: bool) -> TaskProgress:
        """The first stage not yet done, its instruction on the worker's stage line."""
        total = len(self._stages)
        if success:
            return TaskProgress("done", DONE, total, total)
        for index, (stage, check) in enumerate(self._stages):
            if not self._ask(check, stage.done_when):
                return TaskProgress(
                    stage.name, stage.instruction, index, total, stage.relative_to or ""
                )
        last = self._stages[-1][0]
        return TaskProgress(last.name, last.instruction, total - 1, total, last.relative_to or "")


def generic_progress(instruction: str, success: bool, held: list[str]) -> TaskProgress:
    """For a task that declares no stages: its instruction, what the hand holds, done."""
    if success:
        return TaskProgress("done", DONE, 1, 1)
    if held:
        return TaskProgress("grasped", f"{held[0]} grasped. {instruction}", 0, 1, held[0])
    return TaskProgress("reach", instruction, 0, 1)
