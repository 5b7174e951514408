"""Success and the worker's stage line for one robosuite task: robosuite's own tests, or the
functions the task's declaration names (`crowdteleop.sim.declared`)."""

from __future__ import annotations

from typing import Any

from crowdteleop.sim.declared import DeclaredChecks, generic_progress
from crowdteleop.sim.robosuite_backend import tasks
from crowdteleop.sim.types import TaskProgress
from crowdteleop.tasks import TaskSpec


class TaskJudge:
    """Answers "is it done?" and "what should the worker do now?" for one environment."""

    def __init__(self, task: TaskSpec, env: Any) -> None:
        self._task = task
        self._env = env
        self._declared = DeclaredChecks(task, env)

    @property
    def errors(self) -> int:
        """How often the task's declared functions raised."""
        return self._declared.errors

    def success(self) -> bool:
        if self._declared.declares_success:
            return self._declared.success()
        return bool(self._env._check_success())

    def progress(self, success: bool, grasped: tasks.Grasped) -> TaskProgress:
        if self._declared.declares_stages:
            return self._declared.staged_progress(success)
        if not self._declared.declares_success and tasks.has_own_progress(self._env):
            return tasks.progress(self._env, success, grasped)
        held = [obj.name for obj in tasks.active_objects(self._env) if grasped(obj)]
        return generic_progress(self._task.instruction, success, held)
