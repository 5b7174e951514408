"""Success and the worker's stage line for one task: robosuite's own tests, or the functions a
task's declaration names (`TaskSpec.success`, `TaskSpec.stages`).

A declared function runs on every control step inside the session; one that raises must not end
the session or lose its recording. Its answer counts as "not yet", the failure is counted in
`errors` and logged once per function.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from crowdteleop.sim.robosuite_backend import tasks
from crowdteleop.sim.types import TaskProgress
from crowdteleop.tasks import Stage, TaskSpec, resolve

logger = logging.getLogger(__name__)

Check = Callable[[Any], Any]  # a robosuite environment -> truthy when done


class TaskJudge:
    """Answers "is it done?" and "what should the worker do now?" for one environment."""

    def __init__(self, task: TaskSpec, env: Any) -> None:
        self._task = task
        self._env = env
        self._success: Check | None = resolve(task.success) if task.success else None
        self._stages: list[tuple[Stage, Check]] = [
            (stage, resolve(stage.done_when)) for stage in task.stages
        ]
        self.errors = 0
        self._logged: set[str] = set()

    def _ask(self, check: Check, reference: str) -> bool:
        try:
            return bool(check(self._env))
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
        if self._success is None:
            return bool(self._env._check_success())
        assert self._task.success is not None
        return self._ask(self._success, self._task.success)

    def progress(self, success: bool, grasped: tasks.Grasped) -> TaskProgress:
        if self._stages:
            return self._staged(success)
        if self._success is None and tasks.has_own_progress(self._env):
            return tasks.progress(self._env, success, grasped)
        return tasks.generic_progress(self._env, self._task.instruction, success, grasped)

    def _staged(self, success: bool) -> TaskProgress:
        total = len(self._stages)
        if success:
            return TaskProgress("done", "Task done: well done!", total, total)
        for index, (stage, check) in enumerate(self._stages):
            if not self._ask(check, stage.done_when):
                return TaskProgress(stage.name, stage.instruction, index, total)
        last = self._stages[-1][0]
        return TaskProgress(last.name, last.instruction, total - 1, total)
