"""Micro and macro averages over trials, as the GhostShell paper defines them.

Paper, Appendix "Per-Task Performance": "The micro-average (mean over all cases
per round) and macro-average (mean of per-category means per round) rows report
the mean±std across rounds", and each per-task cell is "the mean score" of the
five rounds. The paper does not say which standard deviation; we report the
population std over rounds (``ddof=0``, numpy's default) and name it in the output.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass

import numpy as np

#: degrees of freedom of the std over rounds (population std)
DDOF = 0


@dataclass(frozen=True)
class Averages:
    """``micro``/``macro``: mean over rounds; ``*_std``: std over rounds; ``per_round_*``: one value per round;
    ``per_task``: task id -> mean over its rounds; ``per_category``: category -> mean over its tasks' scores."""

    micro: float
    micro_std: float
    macro: float
    macro_std: float
    per_round_micro: list[float]
    per_round_macro: list[float]
    per_task: dict[int, float]
    per_category: dict[str, float]
    rounds: int


def averages(scores: dict[tuple[int, int], float], categories: dict[int, str]) -> Averages:
    """Averages of ``scores[(task, round)]`` (rounds may be any ints; a round counts only
    the tasks scored in it). Raises ValueError on an empty input or an unknown task."""
    if not scores:
        raise ValueError("no scores to average")
    unknown = {t for t, _ in scores} - set(categories)
    if unknown:
        raise ValueError(f"no category for task(s) {sorted(unknown)}")
    by_round: dict[int, dict[int, float]] = defaultdict(dict)
    by_task: dict[int, list[float]] = defaultdict(list)
    for (task, rnd), s in sorted(scores.items()):
        by_round[rnd][task] = s
        by_task[task].append(s)
    micro_r: list[float] = []
    macro_r: list[float] = []
    for rnd in sorted(by_round):
        cells = by_round[rnd]
        micro_r.append(float(np.mean(list(cells.values()))))
        per_cat: dict[str, list[float]] = defaultdict(list)
        for task, s in cells.items():
            per_cat[categories[task]].append(s)
        macro_r.append(float(np.mean([np.mean(v) for v in per_cat.values()])))
    cat_all: dict[str, list[float]] = defaultdict(list)
    for (task, _), s in scores.items():
        cat_all[categories[task]].append(s)
    return Averages(
        micro=float(np.mean(micro_r)), micro_std=float(np.std(micro_r, ddof=DDOF)),
        macro=float(np.mean(macro_r)), macro_std=float(np.std(macro_r, ddof=DDOF)),
        per_round_micro=micro_r, per_round_macro=macro_r,
        per_task={t: float(np.mean(v)) for t, v in sorted(by_task.items())},
        per_category={c: float(np.mean(v)) for c, v in cat_all.items()}, rounds=len(by_round))
