"""A robot's tasks as data: instruction and ground-truth function tokens (the paper's format).

``tasks.json``: ``{"tasks": [{"id": 1, "category": "...", "instruction": "...", "ground_truth": "..."}]}``.
Tasks without a ground truth (the paper's long-horizon ones) can be listed but not run or scored.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from robots.datatypes import RobotDataError

__all__ = ["Task", "get_task", "load_tasks"]


@dataclass(frozen=True)
class Task:
    """One task: ``ground_truth`` is None for tasks that are described but not scored."""

    id: int
    category: str
    instruction: str
    ground_truth: str | None


def load_tasks(path: Path) -> dict[int, Task]:
    """All tasks in ``path`` by id (:class:`RobotDataError` naming the file when it is malformed)."""
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
        return {int(t["id"]): Task(int(t["id"]), str(t["category"]), str(t["instruction"]), t.get("ground_truth"))
                for t in doc["tasks"]}
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise RobotDataError(f"{path}: not a task file ({type(e).__name__}: {e})") from None


def get_task(tasks: Mapping[int, Task], task_id: int, robot: str = "") -> Task:
    """The runnable task ``task_id``; ValueError lists the valid ids."""
    if task_id not in tasks or tasks[task_id].ground_truth is None:
        valid = sorted(i for i, t in tasks.items() if t.ground_truth is not None)
        who = f"{robot} has " if robot else ""
        if not valid:
            raise ValueError(f"no runnable task {task_id}; {who}no tasks with a ground truth")
        raise ValueError(f"no runnable task {task_id}; {who}tasks with ground truth: {valid[0]}-{valid[-1]}")
    return tasks[task_id]
