"""Tasks: what each one is (`TaskSpec`), the built-in ones and the catalogue plug-ins add to.

Pure Python: nothing here loads a simulator or a plug-in's environment code.
"""

from crowdteleop.tasks.catalogue import (
    ENTRY_POINT_GROUP,
    TASK_FILES_VARIABLE,
    Catalogue,
    catalogue,
    get_task,
    load_catalogue,
    task_names,
    tasks_in_file,
)
from crowdteleop.tasks.spec import (
    PLATFORM_GRIPPERS,
    ROBOSUITE_ARMS,
    ROBOSUITE_DEFAULT_GRIPPER,
    Backend,
    FastPath,
    Stage,
    TaskSpec,
    import_env_module,
    read_scene,
    resolve,
)

__all__ = [
    "ENTRY_POINT_GROUP",
    "PLATFORM_GRIPPERS",
    "ROBOSUITE_ARMS",
    "ROBOSUITE_DEFAULT_GRIPPER",
    "TASK_FILES_VARIABLE",
    "Backend",
    "Catalogue",
    "FastPath",
    "Stage",
    "TaskSpec",
    "catalogue",
    "get_task",
    "import_env_module",
    "load_catalogue",
    "read_scene",
    "resolve",
    "task_names",
    "tasks_in_file",
]
