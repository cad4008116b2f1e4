"""``ghostshell eval --workers N``: jobs in worker processes (one interpreter lock held two workers to
1.12x), each job timed (what an LLM's latency adds), a dying worker fails its job only, a cancelled
sweep stops its workers."""

from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path
from typing import Any

import anyio
import pytest

from host.cli import main as cli
from host.tools.eval.report import job_times, summarise_timing, sweep_times, write_reports
from host.tools.eval.sweep import SweepConfig, run_job, system_prompt
from host.tools.eval.workers import STOP_S, WORKER_ERROR, run_in_processes
from support.fake_llm import FakeLLM, Handler

pytestmark = pytest.mark.timeout(240)


def test_parallel_jobs_run_in_worker_processes_each_timed(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "ev"
    assert cli(["eval", "--llm", "ground-truth", "--tasks", "1,2,3", "--trials", "1", "--workers", "2",
                "--no-plots", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    doc = json.loads((out / "eval.json").read_text())
    recs = doc["records"]
    pids = {r["pid"] for r in recs}
    assert os.getpid() not in pids and len(pids) == 2, pids  # two worker processes, not this one's event loop
    for r in recs:
        assert 0 < r["run"]["wall_s"] <= r["wall_s"] and r["llm_s"] == 0.0, r
        assert f"task {r['task']} trial 0: DSBC 1.00, run done, {r['wall_s']:.2f} s (LLM 0.00 s, run " in printed
    timing = doc["summary"]["timing"]
    assert timing["workers"] == 2 and timing["backend"] == "local" and timing["jobs"] == 3
    assert 0 < timing["sweep_wall_s"] and timing["max_wall_s"] == max(r["wall_s"] for r in recs)
    assert "wall time: sweep" in printed and "(2 workers)" in printed
    assert "| wall (LLM) |" in (out / "eval.md").read_text()


def test_one_worker_runs_jobs_in_this_process(tmp_path: Path) -> None:
    out = tmp_path / "ev"
    assert cli(["eval", "--llm", "ground-truth", "--tasks", "1,2", "--trials", "1", "--no-run", "--quiet",
                "--out", str(out)]) == 0
    assert {r["pid"] for r in json.loads((out / "eval.json").read_text())["records"]} == {os.getpid()}


class _DiesOnArrival:
    """Unpickled (in the worker) as ``os._exit(3)``: a worker process that dies."""

    def __reduce__(self) -> tuple[Any, tuple[int]]:
        return os._exit, (3,)


def test_a_worker_that_dies_fails_its_job_not_the_sweep() -> None:
    records: list[dict[str, Any]] = []
    jobs = [(1, 0), (2, 0), (3, 0)]
    anyio.run(run_in_processes, run_job, _DiesOnArrival(), jobs, "system", records.append, 2)
    # each of the two slots lost the job it sent, then stopped: a worker that never finished a job is not restarted
    assert len(records) == 2 and {(r["task"], r["trial"]) for r in records} < set(jobs), records
    assert all(r["status"] == WORKER_ERROR and "exited (status 3)" in r["error"] for r in records), records


def _children() -> list[int]:
    """Pids of this process's living children (from /proc)."""
    kids = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == os.getpid() and fields[0] != "Z":
            kids.append(int(stat.parent.name))
    return kids


def test_a_cancelled_sweep_stops_its_workers(fake_llm: FakeLLM, tmp_path: Path) -> None:
    asked = threading.Event()
    release = threading.Event()

    def hang(h: Handler, f: FakeLLM) -> None:  # the LLM never answers while the test runs
        asked.set()
        release.wait(60)

    fake_llm.responder = hang
    cfg = SweepConfig(llm="openai:m", tasks=[1, 2], trials=1, base_url=fake_llm.base_url, api_key="k", workers=2,
                      out=tmp_path / "ev", execute=False, max_retries=0)
    before = set(_children())
    records: list[dict[str, Any]] = []

    async def sweep_then_cancel() -> float:
        async with anyio.create_task_group() as tg:
            tg.start_soon(run_in_processes, run_job, cfg, [(1, 0), (2, 0)], system_prompt(cfg), records.append, 2)
            await anyio.to_thread.run_sync(asked.wait, 60)  # a worker is inside a job, waiting on the LLM
            t0 = time.monotonic()
            tg.cancel_scope.cancel()
        return time.monotonic() - t0

    try:
        took = anyio.run(sweep_then_cancel)
    finally:
        release.set()
    assert asked.is_set() and records == []
    assert set(_children()) <= before  # the workers are gone (reaped), none left behind
    assert took < STOP_S, took  # they stopped on SIGTERM; none needed killing


def test_timing_summary_and_lines() -> None:
    recs = [{"task": 1, "trial": 0, "wall_s": 2.0, "llm_s": 1.5, "run": {"wall_s": 0.5}},
            {"task": 1, "trial": 1, "wall_s": 4.0, "llm_s": 2.5, "run": {"wall_s": 1.5}},
            {"task": 2, "trial": 0}]  # a record of a version that did not time jobs
    t = summarise_timing(recs, {"sweep_wall_s": 3.5, "workers": 2, "backend": "ray"})
    assert (t["jobs"], t["wall_s"], t["llm_s"], t["run_wall_s"], t["max_wall_s"]) == (2, 3.0, 2.0, 1.0, 4.0)
    assert t["per_task"] == {1: {"wall_s": 3.0, "llm_s": 2.0, "run_wall_s": 1.0}}
    assert sweep_times(t) == ("wall time: sweep 3.5 s (2 workers, Ray); per job mean 3.00 s, max 4.00 s "
                              "(LLM 2.00 s, run on the board 1.00 s; 2 jobs)")
    assert job_times(recs[0]) == ", 2.00 s (LLM 1.50 s, run 0.50 s)" and job_times(recs[2]) == ""


def test_reports_show_each_tasks_wall_time(tmp_path: Path) -> None:
    recs = [{"task": t, "trial": 0, "status": "done", "dsbc": 1.0, "wall_s": 1.25 * t, "llm_s": 0.5,
             "run": {"wall_s": 1.25 * t - 0.5, "clean": True}} for t in (1, 2)]
    summary = write_reports(tmp_path, {"llm": "ground-truth", "suite": "hri", "robot": "coco", "workers": 1,
                                       "sweep_wall_s": 3.9, "backend": "local"}, recs)
    assert summary["timing"]["per_task"][2]["wall_s"] == 2.5
    md = (tmp_path / "eval.md").read_text()
    assert "| 1 | atomic | 1.00 ± 0.00 | – | 1/1 | 1.25 s (0.50 s) |" in md and "wall time: sweep 3.9 s (1 worker)" in md
