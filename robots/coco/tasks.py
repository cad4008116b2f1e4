"""The GhostShell paper's CoCo tasks as data: instruction and ground-truth function tokens."""

from __future__ import annotations

from pathlib import Path

from robots import tasks as _tasks
from robots.tasks import Task

__all__ = ["TASKS_PATH", "Task", "get_task", "load_tasks"]

TASKS_PATH = Path(__file__).resolve().parent / "tasks.json"


def load_tasks(path: Path = TASKS_PATH) -> dict[int, Task]:
    """All tasks by id (ids 1-30 have ground truth; 31-33 are long-horizon, without)."""
    return _tasks.load_tasks(path)


def get_task(task_id: int) -> Task:
    """The task with ``task_id``; a clear error lists the valid ids."""
    return _tasks.get_task(load_tasks(), task_id)
