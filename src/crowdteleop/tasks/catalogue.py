"""The catalogue: the built-in tasks plus what plug-ins declare.

Plug-ins are found two ways, both read once per process:

- an installed package's entry point in the group ``crowdteleop.tasks``, whose object is a
  `TaskSpec`, a sequence of them, or a function returning either;
- YAML files listed in ``CROWDTELEOP_TASK_FILES`` (separated like ``PATH``), each a ``tasks:``
  list of declarations with `TaskSpec`'s fields.

A plug-in that cannot be read, or that reuses a name, is left out and named in `problems`: the
other tasks still work, and asking for a missing one says why it is missing.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import os
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from importlib.metadata import EntryPoint, entry_points
from pathlib import Path
from typing import Any

import yaml
from pydantic import TypeAdapter, ValidationError

from crowdteleop.errors import ConfigError, UnknownTaskError
from crowdteleop.tasks.builtin import BUILTIN_TASKS
from crowdteleop.tasks.spec import TaskSpec

ENTRY_POINT_GROUP = "crowdteleop.tasks"
TASK_FILES_VARIABLE = "CROWDTELEOP_TASK_FILES"

logger = logging.getLogger(__name__)
_declaration = TypeAdapter(TaskSpec)


@dataclass(frozen=True)
class Catalogue:
    """Every task this process knows, and the plug-ins it could not take, in words."""

    tasks: Mapping[str, TaskSpec]
    problems: tuple[str, ...] = ()

    def get(self, name: str) -> TaskSpec:
        try:
            return self.tasks[name]
        except KeyError:
            why = f" (plug-ins left out: {'; '.join(self.problems)})" if self.problems else ""
            raise UnknownTaskError(
                f"unknown task {name!r}; choose one of: {', '.join(self.tasks)}{why}"
            ) from None

    def names(self) -> list[str]:
        return list(self.tasks)


class _Collector:
    """Adds declarations in order; a name already taken is a problem, not an override."""

    def __init__(self) -> None:
        self.tasks: dict[str, TaskSpec] = {}
        self.problems: list[str] = []

    def add(self, task: TaskSpec) -> None:
        taken = self.tasks.get(task.name)
        if taken is not None:
            self.problems.append(
                f"{task.source}: task {task.name!r} is already declared by {taken.source}"
            )
            return
        self.tasks[task.name] = task

    def catalogue(self) -> Catalogue:
        return Catalogue(dict(self.tasks), tuple(self.problems))


def _parse(item: Any, source: str) -> TaskSpec:
    if not isinstance(item, Mapping):
        raise ConfigError(f"a task declaration is a mapping of TaskSpec's fields, got {item!r}")
    try:
        return _declaration.validate_python({"source": source, **item})
    except ValidationError as error:
        details = "; ".join(
            f"{'.'.join(map(str, e['loc'])) or 'task'}: {e['msg']}" for e in error.errors()
        )
        raise ConfigError(f"task {item.get('name', '?')!r}: {details}") from None


def tasks_in_file(path: Path) -> list[TaskSpec]:
    """The declarations of one YAML file, or a `ConfigError` naming the file and the field."""
    try:
        document = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as error:
        raise ConfigError(f"task file {path}: {error}") from None
    items = document.get("tasks") if isinstance(document, Mapping) else None
    if not isinstance(items, list):
        raise ConfigError(f"task file {path}: expected a top-level 'tasks:' list")
    source = f"file {path}"
    try:
        return [_parse(item, source) for item in items]
    except ConfigError as error:
        raise ConfigError(f"task file {path}: {error}") from None


def _entry_point_tasks(entry: EntryPoint) -> list[TaskSpec]:
    source = f"entry point {entry.name!r} ({entry.value})"
    declared = entry.load()
    if callable(declared) and not isinstance(declared, TaskSpec):
        declared = declared()
    found = [declared] if isinstance(declared, TaskSpec) else list(declared)
    wrong = [item for item in found if not isinstance(item, TaskSpec)]
    if wrong:
        raise ConfigError(f"expected TaskSpec objects, got {wrong[0]!r}")
    return [
        dataclasses.replace(task, source=source) if task.source == "built-in" else task
        for task in found
    ]


def _plugin_sources(environ: Mapping[str, str]) -> Iterator[tuple[str, Any]]:
    """(where, how to read it) for every entry point, then every task file."""
    for entry in entry_points(group=ENTRY_POINT_GROUP):
        yield (
            f"entry point {entry.name!r} ({entry.value})",
            functools.partial(_entry_point_tasks, entry),
        )
    for text in environ.get(TASK_FILES_VARIABLE, "").split(os.pathsep):
        if text.strip():
            yield f"file {text}", functools.partial(tasks_in_file, Path(text.strip()))


def load_catalogue(environ: Mapping[str, str] | None = None) -> Catalogue:
    """Built-in tasks, then every plug-in's; a plug-in's failure is kept as a problem."""
    collector = _Collector()
    for task in BUILTIN_TASKS:
        collector.add(task)
    for where, read in _plugin_sources(os.environ if environ is None else environ):
        try:
            declared: Iterable[TaskSpec] = read()
            for task in declared:
                collector.add(task)
        except Exception as error:  # a plug-in's own code may raise anything
            collector.problems.append(f"{where}: {error}")
    found = collector.catalogue()
    for problem in found.problems:
        logger.warning("task plug-in left out: %s", problem)
    return found


@functools.cache
def catalogue() -> Catalogue:
    """This process's catalogue, read on first use (`catalogue.cache_clear()` reads it again)."""
    return load_catalogue()


def get_task(name: str) -> TaskSpec:
    return catalogue().get(name)


def task_names() -> list[str]:
    return catalogue().names()
