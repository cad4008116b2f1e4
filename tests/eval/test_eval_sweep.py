"""``ghostshell eval`` end to end against a local OpenAI-compatible server: DSBC reproduced
independently from the replies the server sent, runs on real lockstep boards, resuming."""

from __future__ import annotations

import json
import threading
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np
import pytest

from host.cli import main as cli
from host.tools.eval.dsbc import dsbc
from host.tools.eval.paper import hri_tasks
from host.tools.eval.stats import averages
from support.fake_llm import FakeLLM, Handler, replay, stream_body

TASKS = hri_tasks()
BY_INSTRUCTION = {t.instruction: t for t in TASKS.values()}


def serve_replies(fake: FakeLLM) -> tuple[list[tuple[int, str]], list[str]]:
    """Answer task N's k-th request with a fixed reply: the ground truth first, then a worse one."""
    served: list[tuple[int, str]] = []
    systems: list[str] = []
    counts: Counter[int] = Counter()
    lock = threading.Lock()

    def respond(h: Handler, f: FakeLLM) -> None:
        msgs = f.requests[-1]["json"]["messages"]
        systems.append(msgs[0]["content"])
        task = BY_INSTRUCTION[msgs[1]["content"]]
        with lock:
            k = counts[task.id]
            counts[task.id] += 1
        reply = ["Sure! " + task.ground_truth, 'Okay. <head_act action="shake"/>', "I can't do that."][k % 3]
        served.append((task.id, reply))
        replay(stream_body([reply[i:i + 5] for i in range(0, len(reply), 5)]), split=11)(h, f)

    fake.responder = respond
    return served, systems


def test_eval_reproduces_dsbc_from_the_served_replies(fake_llm: FakeLLM, tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    served, systems = serve_replies(fake_llm)
    out = tmp_path / "ev"
    args = ["eval", "--llm", "openai:gpt-4.1", "--base-url", fake_llm.base_url, "--api-key", "k",
            "--tasks", "1,3", "--trials", "2", "--workers", "2", "--out", str(out)]
    assert cli(args) == 0
    doc = json.loads((out / "eval.json").read_text())
    recs = doc["records"]
    assert len(recs) == 4 and len(served) == 4
    # independently: the score of every reply the server sent, from the DSBC function alone
    want = sorted((t, round(dsbc(TASKS[t].ground_truth, r), 9)) for t, r in served)
    assert sorted((r["task"], round(r["dsbc"], 9)) for r in recs) == want
    assert {(r["task"], r["reply"]) for r in recs} == set(served)
    # micro/macro as the paper defines them, recomputed by hand
    per_round = defaultdict(list)
    for r in recs:
        per_round[r["trial"]].append(dsbc(TASKS[r["task"]].ground_truth, r["reply"]))
    micro = [np.mean(v) for v in per_round.values()]
    s = doc["summary"]
    assert s["micro"] == pytest.approx(np.mean(micro)) and s["micro_std"] == pytest.approx(np.std(micro))
    assert doc["paper_model"] == "GPT-4.1" and s["per_task"]["1"]["paper"] == TASKS[1].paper_dsbc["GPT-4.1"]
    # the system prompt is exactly `ghostshell prompt`'s
    capsys.readouterr()
    assert cli(["prompt"]) == 0
    printed = capsys.readouterr().out
    assert set(systems) == {printed}
    # every reply ran on a real lockstep board; the ground truth runs clean
    gt_runs = [r["run"] for r in recs if r["reply"].startswith("Sure!")]
    assert gt_runs and all(run["clean"] and run["outcome"] == "done" for run in gt_runs)
    assert all((out / "runs" / f"task-{r['task']:02d}-trial-{r['trial']}" / "summary.json").exists() for r in recs)
    md = (out / "eval.md").read_text()
    assert "micro" in md and "| 1 | atomic |" in md and (out / "eval.png").stat().st_size > 1000


def test_interrupted_sweep_continues_where_it_stopped(fake_llm: FakeLLM, tmp_path: Path) -> None:
    served, _ = serve_replies(fake_llm)
    out = tmp_path / "ev"
    base = ["eval", "--llm", "openai:some-model", "--base-url", fake_llm.base_url, "--api-key", "k",
            "--tasks", "1-2", "--no-run", "--out", str(out)]
    assert cli(base + ["--trials", "1"]) == 0
    assert len(fake_llm.requests) == 2
    with (out / "results.jsonl").open("a") as f:
        f.write('{"task": 2, "trial": 1, "sta')  # the line being written when the sweep was killed
    assert cli(base + ["--trials", "3"]) == 0
    assert len(fake_llm.requests) == 6  # only the 4 missing jobs were asked
    doc = json.loads((out / "eval.json").read_text())
    assert sorted((r["task"], r["trial"]) for r in doc["records"]) == [(t, k) for t in (1, 2) for k in range(3)]
    assert doc["paper_model"] is None and doc["summary"]["rounds"] == 3
    # a different sweep in the same folder is refused, nothing lost
    assert cli(base[:2] + ["openai:other"] + base[3:] + ["--trials", "1"]) == 2


def test_llm_failures_are_recorded_and_retried_next_time(fake_llm: FakeLLM, tmp_path: Path) -> None:
    fake_llm.responder = lambda h, f: h.send_json_error(400, b'{"error": {"message": "no such model"}}')
    out = tmp_path / "ev"
    args = ["eval", "--llm", "openai:m", "--base-url", fake_llm.base_url, "--api-key", "k", "--tasks", "1",
            "--trials", "1", "--no-run", "--out", str(out)]
    assert cli(args) == 1
    lines = [json.loads(x) for x in (out / "results.jsonl").read_text().splitlines()]
    assert lines[0]["status"] == "llm_error" and "no such model" in lines[0]["error"]
    served, _ = serve_replies(fake_llm)
    assert cli(args) == 0 and len(served) == 1


def test_averages_follow_the_paper() -> None:
    cats = {1: "a", 2: "a", 3: "b"}
    scores = {(1, 0): 1.0, (2, 0): 0.0, (3, 0): 1.0, (1, 1): 1.0, (2, 1): 1.0, (3, 1): 0.0}
    av = averages(scores, cats)
    assert av.per_round_micro == pytest.approx([2 / 3, 2 / 3])
    assert av.per_round_macro == pytest.approx([0.75, 0.5])  # mean of per-category means per round
    assert (av.macro, av.macro_std) == pytest.approx((0.625, 0.125))
    with pytest.raises(ValueError):
        averages({}, cats)


def test_bad_arguments_are_clear(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli(["eval", "--llm", "openai:m", "--tasks", "0-40", "--out", str(tmp_path)]) == 2
    assert "no task(s)" in capsys.readouterr().err
    assert cli(["eval", "--llm", "openai:m", "--native-tools", "--tasks", "1", "--out", str(tmp_path)]) == 2


def test_eval_with_anthropic_streaming(fake_llm: FakeLLM, tmp_path: Path) -> None:
    from support.fake_anthropic import stream as anthropic_stream

    reply = "Sure! " + TASKS[2].ground_truth
    fake_llm.responder = replay(anthropic_stream([reply[:7], reply[7:]]), split=6)
    out = tmp_path / "ev"
    assert cli(["eval", "--llm", "anthropic:claude-sonnet-4-20250514", "--base-url", f"http://127.0.0.1:{fake_llm.port}",
                "--api-key", "k", "--tasks", "2", "--trials", "1", "--no-run", "--out", str(out)]) == 0
    doc = json.loads((out / "eval.json").read_text())
    (rec,) = doc["records"]
    assert rec["reply"] == reply and rec["dsbc"] == pytest.approx(dsbc(TASKS[2].ground_truth, reply))
    assert doc["paper_model"] == "Claude-Sonnet-4"
    req = fake_llm.requests[0]
    assert req["path"] == "/v1/messages" and req["json"]["system"] and req["json"]["messages"][0]["role"] == "user"
