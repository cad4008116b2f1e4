"""``ghostshell eval`` without a model (issue 16, item 6): the whole report from the command line.

``--llm ground-truth`` answers each task with its own ground truth (micro = macro = 1.0, every run
clean); ``--llm scripted --replies FILE`` with the replies in FILE, in chat's ``---`` block format,
either in ``--tasks`` order or headed ``--- task N``. Each writes eval.json, eval.md and eval.png.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.timeout(300)


def _eval(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "host", "eval", *args], capture_output=True, text=True, timeout=280,
                          stdin=subprocess.DEVNULL)


def _report(out: Path) -> dict:
    for name in ("eval.json", "eval.md", "eval.png", "results.jsonl"):
        assert (out / name).exists(), name
    return json.loads((out / "eval.json").read_text())


def test_ground_truth_scores_one(tmp_path: Path) -> None:
    out = tmp_path / "gt"
    r = _eval("--llm", "ground-truth", "--tasks", "1,9,26", "--trials", "1", "--workers", "2", "--out", str(out),
              "--no-plots")
    assert r.returncode == 0, r.stderr[-3000:]
    s = _report(out)["summary"]
    assert s["micro"] == 1.0 and s["macro"] == 1.0, s
    assert s["ran_clean"] == s["runs"] == 3, s
    runs = sorted((out / "runs").iterdir())
    assert len(runs) == 3 and all((r / "summary.json").is_file() for r in runs), runs
    assert not list((out / "runs").glob("*/*.png")), "--no-plots: the runs draw no plots"
    assert "micro 1.00 ± 0.00, macro 1.00 ± 0.00; ran clean 3/3" in r.stdout, r.stdout


@pytest.mark.parametrize("headed", [False, True], ids=["in-order", "task-headers"])
def test_scripted_replies_are_scored_and_run(headed: bool, tmp_path: Path) -> None:
    from robots.registry import load_robot

    tasks = load_robot().tasks
    right, wrong = tasks[1].ground_truth, '<head_act action="shake"/>'  # task 2's answer is a nod
    replies = tmp_path / "replies.txt"
    if headed:  # any order, and a reply for a task not asked for (ignored)
        replies.write_text(f"--- task 2\n{wrong}\n--- task 30\n<wave/>\n--- task 1\n{right}\n", encoding="utf-8")
    else:
        replies.write_text(f"{right}\n---\n{wrong}\n", encoding="utf-8")
    out = tmp_path / "scripted"
    r = _eval("--llm", "scripted", "--replies", str(replies), "--tasks", "1-2", "--trials", "1", "--out", str(out))
    assert r.returncode == 0, r.stderr[-3000:]
    doc = _report(out)
    by_task = {rec["task"]: rec for rec in doc["records"]}
    assert by_task[1]["dsbc"] == 1.0 and by_task[1]["reply"] == right
    assert by_task[2]["dsbc"] < 1.0 and by_task[2]["reply"] == wrong
    assert all(rec["run"]["outcome"] == "done" for rec in doc["records"])  # both ran on the board
    assert len(list((out / "runs").glob("*/joints.png"))) == 2  # each run draws its plots by default
    assert doc["summary"]["micro"] == pytest.approx((1.0 + by_task[2]["dsbc"]) / 2)


def test_another_replies_file_is_another_sweep(tmp_path: Path) -> None:
    first, second = tmp_path / "a.txt", tmp_path / "b.txt"
    first.write_text("<head_act/>\n", encoding="utf-8")
    second.write_text("<wave/>\n", encoding="utf-8")
    out = tmp_path / "sweep"
    assert _eval("--llm", "scripted", "--replies", str(first), "--tasks", "2", "--trials", "1", "--no-run",
                 "--out", str(out)).returncode == 0
    again = _eval("--llm", "scripted", "--replies", str(second), "--tasks", "2", "--trials", "1", "--no-run",
                  "--out", str(out))
    assert again.returncode == 2 and "holds a different sweep" in again.stderr, again.stderr
