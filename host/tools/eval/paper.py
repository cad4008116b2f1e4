"""A robot's evaluation data: its tasks, and the published numbers where a paper has them.

Every robot with tasks (robot.toml ``tasks``) can be evaluated: :func:`hri_tasks` gives its tasks
with a ground truth. A robot whose package also names ``paper_results`` in ``[data]`` (the default robot's: a copy
of ``ghostshell_tasks.json`` shipped with the GhostShell paper's tables: the 30 grounded HRI tasks
with per-task DSBC for 21 models, mean of 5 rounds; the 15 native-call ablation tasks with the
expected pattern and pass/fail of both modes for GPT-4.1; the summary numbers) gets those beside
its scores, and the ablation. Every function takes the robot (default: the default robot).
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

from robots.description import Robot
from robots.registry import load_robot


@dataclass(frozen=True)
class EvalTask:
    """One HRI task: ``id`` 1-30, ``category`` (the paper's behavioural mode), the
    ``instruction`` given to the LLM, the ``ground_truth`` program, and the paper's
    per-model mean DSBC (``paper_dsbc[model]``)."""

    id: int
    category: str
    instruction: str
    ground_truth: str
    paper_dsbc: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class AblationTask:
    """One native-call ablation task: ``expected`` pattern and the paper's verdicts."""

    id: int
    category: str
    instruction: str
    expected: str
    paper_native: bool
    paper_function_token: bool


def _robot(robot: Robot | None) -> Robot:
    return load_robot() if robot is None else robot


def paper_data(robot: Robot | None = None) -> Path | None:
    """The robot's published-numbers file (robot.toml ``[data] paper_results``), None when it has none."""
    return _robot(robot).data.get("paper_results")


@lru_cache(maxsize=8)
def _load(path: Path) -> dict[str, Any]:
    return dict(json.loads(path.read_text(encoding="utf-8")))


def _doc(robot: Robot | None = None) -> dict[str, Any]:
    path = paper_data(robot)
    return _load(path) if path is not None else {}


def hri_tasks(robot: Robot | None = None) -> dict[int, EvalTask]:
    """The robot's tasks that have a ground truth, by id (with the paper's DSBC where it has them)."""
    doc = _doc(robot)
    if doc:
        return {t["id"]: EvalTask(t["id"], t["category"], t["instruction"], t["ground_truth"],
                                  dict(t.get("paper_dsbc", {})))
                for t in doc["hri_tasks"] if t.get("ground_truth")}
    return {t.id: EvalTask(t.id, t.category, t.instruction, t.ground_truth)
            for t in _robot(robot).tasks.values() if t.ground_truth}


def ablation_tasks(robot: Robot | None = None) -> dict[int, AblationTask]:
    """The native-call ablation tasks, by id (empty for a robot without the paper's ablation data)."""
    return {t["id"]: AblationTask(t["id"], t["category"], t["instruction"], t["expected"],
                                  bool(t["paper_native_call_passed"]), bool(t["paper_function_token_passed"]))
            for t in _doc(robot).get("native_call_ablation", [])}


def paper_models(robot: Robot | None = None) -> list[str]:
    """The models of the paper's DSBC table, in its column order (empty without paper data)."""
    return list(_doc(robot).get("dsbc_models", []))


def paper_summary(robot: Robot | None = None) -> dict[str, Any]:
    return dict(_doc(robot).get("paper_summary", {}))


def _norm(name: str) -> str:
    n = name.lower().split(":")[-1].split("/")[-1]
    n = re.sub(r"-(\d{8}|\d{4}-\d{2}-\d{2}|latest|preview|instruct)$", "", n)
    n = re.sub(r"(\d)-(\d)(?!\d)", r"\1.\2", n)  # claude-sonnet-4-5 -> 4.5
    return re.sub(r"[^a-z0-9.]", "", n)


#: API ids whose names differ in word order from the paper's columns
ALIASES = {"claude3.7sonnet": "Claude-Sonnet-3.7", "kimik2": "Kimi-K2", "moonshotv1": "Moonshot-v1",
           "qwen3235ba22b": "Qwen3-235B", "qwen3next80ba3b": "Qwen3-next-80B", "llama3.290bvision": "Llama-3.2-90b"}


def match_paper_model(model: str, robot: Robot | None = None) -> str | None:
    """The paper's column for an API model id, or None when the paper has no such model.

    The id is normalised (provider prefix, a trailing date or ``-latest`` dropped,
    ``4-5`` read as ``4.5``, punctuation removed) and compared for equality, so
    ``anthropic:claude-sonnet-4-20250514`` -> ``Claude-Sonnet-4`` and
    ``claude-sonnet-4-5`` -> ``Claude-Sonnet-4.5``, while ``gpt-4.1-mini`` matches nothing.
    """
    m = _norm(model)
    if m in ALIASES:
        return ALIASES[m]
    for name in paper_models(robot):
        if _norm(name) == m:
            return name
    return None


def parse_task_spec(spec: str, valid: list[int]) -> list[int]:
    """``"1-30"``, ``"1,3,5-7"`` or ``"all"`` -> sorted ids; unknown ids, and no ids at all (``""``), raise ValueError."""
    if spec.strip().lower() == "all":
        return sorted(valid)
    if not spec.strip():
        raise ValueError("no task ids given; give ids such as 1-30 or 1,3,5-7, or all")
    out: set[int] = set()
    for part in spec.split(","):
        part = part.strip()
        try:
            if "-" in part:
                a, b = (int(x) for x in part.split("-", 1))
                if a > b:
                    raise ValueError(f"bad task range {part!r}: start after end (did you mean {b}-{a}?)")
                out.update(range(a, b + 1))
            else:
                out.add(int(part))
        except ValueError as e:
            if "start after end" in str(e):
                raise
            raise ValueError(f"bad task list {spec!r}; expected e.g. 1-30 or 1,4,7-9") from None
    bad = sorted(out - set(valid))
    if bad:
        raise ValueError(f"no task(s) {bad}; valid: {min(valid)}-{max(valid)}")
    return sorted(out)
