"""The sweep's outputs: ``eval.json``, ``eval.md`` (beside the paper's numbers) and ``eval.png``.

``eval.json``: ``{"config", "paper_model", "summary", "tasks", "records"}`` where
``records`` is every job (reply, score, per-layer breakdown, run outcome) and
``summary`` the micro/macro means ± std over trials (:mod:`host.tools.eval.stats`) or,
for the ablation, passes per mode beside the paper's; ``summary["timing"]`` the wall times
(:func:`summarise_timing`: the sweep's, and per job and per task what the LLM and the board run took).
"""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from host.tools.eval.paper import ablation_tasks, hri_tasks, match_paper_model, paper_summary
from robots.description import Robot
from robots.registry import DEFAULT_ROBOT, load_robot
from host.tools.eval.stats import DDOF, averages


def _fmt(x: float | None) -> str:
    return "–" if x is None else f"{x:.2f}"


def _robot(config: dict[str, Any]) -> Robot:
    return load_robot(str(config.get("robot") or DEFAULT_ROBOT), config.get("robots_dir"))


def summarise_hri(records: list[dict[str, Any]], paper_model: str | None, robot: Robot | None = None) -> dict[str, Any]:
    """Micro/macro over trials, per-task means and clean-run counts, the paper's values beside."""
    tasks = hri_tasks(robot)
    scores = {(r["task"], r["trial"]): float(r["dsbc"]) for r in records}
    out: dict[str, Any] = {"jobs": len(records)}
    if not scores:
        return out
    av = averages(scores, {t: tasks[t].category for t, _ in scores})
    clean: dict[int, list[bool]] = defaultdict(list)
    for r in records:
        if "run" in r:
            clean[r["task"]].append(bool(r["run"]["clean"]))
    per_task = {}
    for t, mean in av.per_task.items():
        cell = [float(r["dsbc"]) for r in records if r["task"] == t]
        per_task[t] = {"category": tasks[t].category, "mean": mean, "std": float(np.std(cell, ddof=DDOF)),
                       "trials": len(cell), "clean": sum(clean[t]) if t in clean else None,
                       "runs": len(clean[t]) if t in clean else 0,
                       "paper": tasks[t].paper_dsbc.get(paper_model) if paper_model else None}
    paper_mean = None
    if paper_model:
        vals = [tasks[t].paper_dsbc[paper_model] for t in av.per_task if paper_model in tasks[t].paper_dsbc]
        paper_mean = float(np.mean(vals)) if vals else None
    runs = [r["run"] for r in records if "run" in r]
    out.update({"micro": av.micro, "micro_std": av.micro_std, "macro": av.macro, "macro_std": av.macro_std,
                "rounds": av.rounds, "std": f"population std over rounds (ddof={DDOF})",
                "per_round_micro": av.per_round_micro, "per_round_macro": av.per_round_macro,
                "per_category": av.per_category, "per_task": per_task,
                "paper_mean_of_tasks": paper_mean,
                "ran_clean": sum(bool(r["clean"]) for r in runs), "runs": len(runs),
                "fell": sum(bool(r.get("fell")) for r in runs),
                "runs_with_failed_calls": sum(1 for r in runs if (r.get("failed_calls") or 0) > 0)})
    return out


def summarise_ablation(records: list[dict[str, Any]], native: bool, robot: Robot | None = None) -> dict[str, Any]:
    """Passes per task (a task passes in a trial when the judge passes its timeline)."""
    tasks = ablation_tasks(robot)
    by_task: dict[int, list[bool]] = defaultdict(list)
    for r in records:
        if "passed" in r:
            by_task[r["task"]].append(bool(r["passed"]))
    per_task = {t: {"category": tasks[t].category, "expected": tasks[t].expected, "passed": sum(v), "trials": len(v),
                    "paper": tasks[t].paper_native if native else tasks[t].paper_function_token}
                for t, v in sorted(by_task.items())}
    # a task counts as completed when it passed in the majority of its trials
    completed = sum(1 for v in by_task.values() if v and sum(v) * 2 > len(v))
    paper = paper_summary(robot)["function_tokens_vs_native"]
    return {"mode": "native" if native else "function_tokens", "completed": completed, "tasks": len(by_task),
            "per_task": per_task, "paper": paper["native_calls" if native else "function_tokens"],
            "paper_other_mode": paper["function_tokens" if native else "native_calls"]}


def _mean(values: list[float]) -> float | None:
    return round(float(np.mean(values)), 3) if values else None


def _times(records: list[dict[str, Any]]) -> dict[str, float | None]:
    """Mean wall seconds of ``records``: the job, the LLM's part, the board run's part (None: not recorded)."""
    return {"wall_s": _mean([r["wall_s"] for r in records if r.get("wall_s") is not None]),
            "llm_s": _mean([r["llm_s"] for r in records if r.get("llm_s") is not None]),
            "run_wall_s": _mean([r["run"]["wall_s"] for r in records if r.get("run", {}).get("wall_s") is not None])}


def summarise_timing(records: list[dict[str, Any]], config: dict[str, Any]) -> dict[str, Any]:
    """Wall times, seconds: ``sweep_wall_s`` (this invocation of the sweep, from the CLI's config; None
    if not given), ``workers``, ``backend`` (``local`` / ``ray``), ``jobs`` (records with a time),
    ``wall_s`` / ``llm_s`` / ``run_wall_s`` (means over jobs: the whole job, asking the LLM, running
    the reply on the board with its start-up and artefacts), ``max_wall_s`` and ``per_task`` (task ->
    the same three means). Records of versions that did not time jobs count as not timed."""
    timed = [r for r in records if r.get("wall_s") is not None]
    by_task: dict[int, list[dict[str, Any]]] = defaultdict(list)
    for r in timed:
        by_task[r["task"]].append(r)
    return {"sweep_wall_s": config.get("sweep_wall_s"), "workers": config.get("workers"),
            "backend": config.get("backend"), "jobs": len(timed), **_times(timed),
            "max_wall_s": round(max(r["wall_s"] for r in timed), 3) if timed else None,
            "per_task": {t: _times(rs) for t, rs in sorted(by_task.items())}}


def _s(x: float | None) -> str:
    return "–" if x is None else f"{x:.2f} s"


def job_times(rec: dict[str, Any]) -> str:
    """``", 1.23 s (LLM 0.45 s, run 0.76 s)"``: one job's wall times for its progress line ("" if untimed)."""
    if rec.get("wall_s") is None:
        return ""
    parts = [f"LLM {_s(rec.get('llm_s'))}"] if rec.get("llm_s") is not None else []
    if rec.get("run", {}).get("wall_s") is not None:
        parts.append(f"run {_s(rec['run']['wall_s'])}")
    return f", {_s(rec['wall_s'])}" + (f" ({', '.join(parts)})" if parts else "")


def sweep_times(timing: dict[str, Any]) -> str:
    """One line: the sweep's wall time and the mean job's (its LLM and board-run parts)."""
    head = "wall time:"
    if timing.get("sweep_wall_s") is not None:
        workers = timing.get("workers")
        how = f" ({workers} worker{'s' if workers != 1 else ''}{', Ray' if timing.get('backend') == 'ray' else ''})"
        head += f" sweep {timing['sweep_wall_s']:.1f} s{how if workers else ''};"
    if not timing.get("jobs"):
        return f"{head} no timed jobs"
    return (f"{head} per job mean {_s(timing['wall_s'])}, max {_s(timing['max_wall_s'])} (LLM {_s(timing['llm_s'])}, "
            f"run on the board {_s(timing['run_wall_s'])}; {timing['jobs']} jobs)")


def write_reports(out: Path, config: dict[str, Any], records: list[dict[str, Any]]) -> dict[str, Any]:
    """Write eval.json, eval.md and eval.png into ``out``; returns the summary (its ``timing``:
    :func:`summarise_timing`)."""
    robot = _robot(config)
    paper_model = config.get("paper_model") or match_paper_model(config["llm"], robot)
    if config["suite"] == "ablation":
        summary = summarise_ablation(records, config["native_tools"], robot)
    else:
        summary = summarise_hri(records, paper_model, robot)
    summary["timing"] = summarise_timing(records, config)
    doc = {"config": config, "paper_model": paper_model, "summary": summary, "records": records}
    (out / "eval.json").write_text(json.dumps(doc, indent=1, ensure_ascii=False, default=str) + "\n", encoding="utf-8")
    (out / "eval.md").write_text(_markdown(config, paper_model, summary), encoding="utf-8")
    _plot(out / "eval.png", config, paper_model, summary)
    return summary


def _markdown(config: dict[str, Any], paper_model: str | None, s: dict[str, Any]) -> str:
    lines = [f"# ghostshell eval: {config['llm']} on {_robot(config).name}", ""]
    if config["suite"] == "ablation":
        mode = "native function calls" if config["native_tools"] else "function tokens"
        lines += [f"Native-call ablation, {mode}: **{s['completed']}/{s['tasks']}** tasks completed "
                  f"(paper, GPT-4.1: {s['paper']}; the other mode: {s['paper_other_mode']}).", "",
                  "| task | category | expected | passed | paper | wall (LLM) |", "| --- | --- | --- | --- | --- | --- |"]
        for t, row in s["per_task"].items():
            lines.append(f"| {t} | {row['category']} | `{row['expected']}` | {row['passed']}/{row['trials']} | "
                         f"{'pass' if row['paper'] else 'fail'} | {_task_times(s, t)} |")
        if "timing" in s:
            lines += ["", sweep_times(s["timing"]) + "."]
        return "\n".join(lines) + "\n"
    if "micro" not in s:
        return "\n".join(lines + ["No finished jobs."]) + "\n"
    ref = paper_model or "no matching model in the paper"
    lines += [f"DSBC over {s['rounds']} trial(s); micro = mean over all cases per round, macro = mean of "
              f"per-category means per round, both mean ± std over rounds ({s['std']}). Paper column: {ref}.", "",
              f"- micro **{s['micro']:.2f} ± {s['micro_std']:.2f}**, macro **{s['macro']:.2f} ± {s['macro_std']:.2f}**"
              + (f" (paper, mean of its per-task values: {s['paper_mean_of_tasks']:.2f})"
                 if s.get("paper_mean_of_tasks") is not None else ""),
              f"- ran clean on the emulated board: {s['ran_clean']}/{s['runs']} (robot fell: {s['fell']}, "
              f"runs with failed calls: {s['runs_with_failed_calls']})", "",
              "| task | category | DSBC (mean ± std) | paper | ran clean | wall (LLM) |",
              "| --- | --- | --- | --- | --- | --- |"]
    for t, row in s["per_task"].items():
        clean = f"{row['clean']}/{row['runs']}" if row["runs"] else "–"
        lines.append(f"| {t} | {row['category']} | {row['mean']:.2f} ± {row['std']:.2f} | {_fmt(row['paper'])} | {clean} "
                     f"| {_task_times(s, t)} |")
    lines += ["", "| category | DSBC |", "| --- | --- |"]
    lines += [f"| {c} | {v:.2f} |" for c, v in s["per_category"].items()]
    if "timing" in s:
        lines += ["", sweep_times(s["timing"]) + ". Wall (LLM): a task's mean job wall time and, of it, the mean "
                  "time asking the LLM."]
    return "\n".join(lines) + "\n"


def _task_times(s: dict[str, Any], task: Any) -> str:
    row = s.get("timing", {}).get("per_task", {}).get(task)
    if not row or row["wall_s"] is None:
        return "–"
    return f"{_s(row['wall_s'])} ({_s(row['llm_s'])})"


def _plot(path: Path, config: dict[str, Any], paper_model: str | None, s: dict[str, Any]) -> None:
    from host.run.artefacts import new_figure

    rows = s.get("per_task", {})
    ids = list(rows)
    fig = new_figure((max(6.0, 0.35 * len(ids) + 2), 3.6))
    ax = fig.subplots()
    x = np.arange(len(ids))
    if config["suite"] == "ablation":
        ours = [rows[t]["passed"] / max(rows[t]["trials"], 1) for t in ids]
        paper = [1.0 if rows[t]["paper"] else 0.0 for t in ids]
        ylabel, ours_label, paper_label = "pass rate", "ours", "paper (GPT-4.1)"
    else:
        ours = [rows[t]["mean"] for t in ids]
        paper = [rows[t]["paper"] if rows[t]["paper"] is not None else np.nan for t in ids]
        ylabel, ours_label, paper_label = "DSBC", "ours", f"paper ({paper_model})" if paper_model else "paper (n/a)"
    err = [rows[t].get("std", 0.0) for t in ids] if config["suite"] != "ablation" else None
    ax.bar(x - 0.2, ours, 0.4, yerr=err, label=ours_label, color="#3b7dd8", capsize=2)
    ax.bar(x + 0.2, paper, 0.4, label=paper_label, color="#bbbbbb")
    ax.set_xticks(x, [str(t) for t in ids], fontsize=7)
    ax.set_ylim(0, 1.05)
    ax.set_xlabel("task")
    ax.set_ylabel(ylabel)
    ax.set_title(f"{config['llm']}: per task, ours vs the paper", fontsize=9)
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
