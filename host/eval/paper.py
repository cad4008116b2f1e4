"""The paper's task data and published numbers (``robots/coco/paper_results.json``).

A copy of ``ghostshell_tasks.json`` shipped with the GhostShell paper's tables:
the 30 grounded HRI tasks (instruction, ground truth, per-task DSBC for 21
models, mean of 5 rounds), the 15 native-call ablation tasks (expected pattern,
pass/fail of both modes for GPT-4.1) and the summary numbers.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import robots.coco

PAPER_DATA = Path(robots.coco.__file__).with_name("paper_results.json")


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


@lru_cache(maxsize=1)
def _doc() -> dict[str, Any]:
    return dict(json.loads(PAPER_DATA.read_text(encoding="utf-8")))


def hri_tasks() -> dict[int, EvalTask]:
    """The grounded HRI tasks that have a ground truth (1-30), by id."""
    return {t["id"]: EvalTask(t["id"], t["category"], t["instruction"], t["ground_truth"], dict(t.get("paper_dsbc", {})))
            for t in _doc()["hri_tasks"] if t.get("ground_truth")}


def ablation_tasks() -> dict[int, AblationTask]:
    """The 15 native-call ablation tasks, by id."""
    return {t["id"]: AblationTask(t["id"], t["category"], t["instruction"], t["expected"],
                                  bool(t["paper_native_call_passed"]), bool(t["paper_function_token_passed"]))
            for t in _doc()["native_call_ablation"]}


def paper_models() -> list[str]:
    """The 21 models of the paper's DSBC table, in its column order."""
    return list(_doc()["dsbc_models"])


def paper_summary() -> dict[str, Any]:
    return dict(_doc()["paper_summary"])


def _norm(name: str) -> str:
    n = name.lower().split(":")[-1].split("/")[-1]
    n = re.sub(r"-(\d{8}|\d{4}-\d{2}-\d{2}|latest|preview|instruct)$", "", n)
    n = re.sub(r"(\d)-(\d)(?!\d)", r"\1.\2", n)  # claude-sonnet-4-5 -> 4.5
    return re.sub(r"[^a-z0-9.]", "", n)


#: API ids whose names differ in word order from the paper's columns
ALIASES = {"claude3.7sonnet": "Claude-Sonnet-3.7", "kimik2": "Kimi-K2", "moonshotv1": "Moonshot-v1",
           "qwen3235ba22b": "Qwen3-235B", "qwen3next80ba3b": "Qwen3-next-80B", "llama3.290bvision": "Llama-3.2-90b"}


def match_paper_model(model: str) -> str | None:
    """The paper's column for an API model id, or None when the paper has no such model.

    The id is normalised (provider prefix, a trailing date or ``-latest`` dropped,
    ``4-5`` read as ``4.5``, punctuation removed) and compared for equality, so
    ``anthropic:claude-sonnet-4-20250514`` -> ``Claude-Sonnet-4`` and
    ``claude-sonnet-4-5`` -> ``Claude-Sonnet-4.5``, while ``gpt-4.1-mini`` matches nothing.
    """
    m = _norm(model)
    if m in ALIASES:
        return ALIASES[m]
    for name in paper_models():
        if _norm(name) == m:
            return name
    return None


def parse_task_spec(spec: str, valid: list[int]) -> list[int]:
    """``"1-30"``, ``"1,3,5-7"`` or ``"all"`` -> sorted ids; unknown ids raise ValueError."""
    if spec.strip().lower() in ("all", ""):
        return sorted(valid)
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
