"""The GhostShell paper's CoCo tasks as data: instruction and ground-truth function tokens."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

TASKS_PATH = Path(__file__).resolve().parent / "tasks.json"


@dataclass(frozen=True)
class Task:
    """One paper task (ids 1-30 have ground truth; 31-33 are long-horizon, without)."""

    id: int
    category: str
    instruction: str
    ground_truth: str | None


def load_tasks(path: Path = TASKS_PATH) -> dict[int, Task]:
    """All tasks by id."""
    doc = json.loads(path.read_text(encoding="utf-8"))
    return {t["id"]: Task(t["id"], t["category"], t["instruction"], t.get("ground_truth")) for t in doc["tasks"]}


def get_task(task_id: int) -> Task:
    """The task with ``task_id``; a clear error lists the valid ids."""
    tasks = load_tasks()
    if task_id not in tasks or tasks[task_id].ground_truth is None:
        valid = sorted(i for i, t in tasks.items() if t.ground_truth is not None)
        raise ValueError(f"no runnable task {task_id}; tasks with ground truth: {valid[0]}-{valid[-1]}")
    return tasks[task_id]
