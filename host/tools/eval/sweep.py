"""``ghostshell eval``: the paper's evaluation of an LLM on a robot's tasks, resumable and parallel.

For every (task, trial) of the robot (``SweepConfig.robot``): the system prompt exactly as
``ghostshell prompt --robot R`` builds it, the task's instruction as the user message, the streamed reply; DSBC
against the ground truth (:func:`host.tools.eval.dsbc.dsbc_breakdown`); the reply
executed on an emulated board in lockstep (:func:`host.run.runner.run_program`
replaying the reply through the shell, one board subprocess per job) to record
whether it ran clean. With ``native_tools`` the functions go to the provider as
tool definitions and the reply runs the native way (:mod:`host.tools.eval.native`).

Every finished job is appended to ``results.jsonl`` in the output folder (one
JSON object per line, flushed), so an interrupted sweep continues where it
stopped; a job whose LLM call failed is retried on the next start. Jobs run
``workers`` at a time, each with its own board: with one worker in this process, with more each in
its own worker process (:mod:`host.tools.eval.workers`: one interpreter's lock would hold the host
sides of several jobs to one core), or on a Ray cluster (:mod:`host.tools.eval.ray_backend`).

Each record carries where it ran (``node``: the host name, ``pid``: the process) and its wall times:
``wall_s`` (the whole job), ``llm_s`` (asking the LLM: what its latency adds; 0 offline) and
``run["wall_s"]`` (the reply's run on the lockstep board, start-up and artefacts included).

Offline (no model): ``llm=GROUND_TRUTH`` answers each task with its own ground truth (micro =
macro = 1.0); ``llm=SCRIPTED`` answers each task with ``SweepConfig.replies[task]`` (from
``ghostshell eval --llm scripted --replies FILE``, :func:`replies_for_tasks`).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import socket
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import IO, Any

import anyio
import anyio.to_thread

from host.tools.eval.dsbc import dsbc_breakdown
from host.tools.eval.native import (ToolCall, expected_pattern, intervals_from_timeline, judge, judge_words,
                              native_program, parse_arguments, tool_schemas)
from host.tools.eval.paper import ablation_tasks, hri_tasks
from host.ghost import GhostError, make_ghost
from host.runtime.binding import signature_registry
from robots.description import Robot
from robots.registry import DEFAULT_ROBOT, load_robot

log = logging.getLogger("host.tools.eval")

RESULTS = "results.jsonl"
CONFIG = "config.json"
#: the LLM spec that answers every task with its ground truth (no model: micro = macro = 1.0)
GROUND_TRUTH = "ground-truth"
#: the LLM spec that answers every task with a reply from a file (``SweepConfig.replies``)
SCRIPTED = "scripted"
#: LLM specs that need no model, key or network
OFFLINE = (GROUND_TRUTH, SCRIPTED)


@dataclass
class SweepConfig:
    """One sweep (the ``ghostshell eval`` flags). ``suite`` is ``"hri"`` (tasks 1-30,
    DSBC) or ``"ablation"`` (the 15 native-call tasks, judged from the timeline)."""

    llm: str
    tasks: list[int]
    robot: str = DEFAULT_ROBOT  # a robot name or folder (robots.registry); robots_dir is searched first
    robots_dir: str | None = None
    trials: int = 5
    suite: str = "hri"
    native_tools: bool = False
    base_url: str | None = None
    api_key: str | None = None
    workers: int = 1
    out: Path = Path("runs/eval")
    vocabulary: str | None = None  # None: the robot's default vocabulary
    mode: str = "async-first"
    prompt_format: str = "code"
    execute: bool = True
    tokens_per_s: float = 30.0
    temperature: float | None = None
    max_retries: int = 2
    native_exec: str = "parallel"  # how one response's tool calls run (host.tools.eval.native.NATIVE_EXEC)
    replies: dict[int, str] | None = None  # llm SCRIPTED: the reply to each task
    mcp_mounts: tuple[Any, ...] = ()  # MCP servers mounted as modules in the prompt and every run (host.mounts)
    plots: bool = True  # each executed reply's run draws timeline.png and joints.png (--no-plots: not)

    def identity(self) -> dict[str, Any]:
        """What must match for a resumed sweep to continue this one."""
        ident = {"llm": self.llm, "robot": self.bot.name, "suite": self.suite, "native_tools": self.native_tools,
                 "native_exec": self.native_exec,
                 "vocabulary": self.vocabulary, "mode": self.mode, "prompt_format": self.prompt_format,
                 "base_url": self.base_url, "tasks": list(self.tasks), "trials": self.trials}
        if self.replies is not None:  # other replies are another sweep
            text = json.dumps(sorted(self.replies.items()), ensure_ascii=False)
            ident["replies_sha256"] = hashlib.sha256(text.encode()).hexdigest()
        return ident


    @property
    def bot(self) -> Robot:
        """The robot (loaded once per process)."""
        return load_robot(self.robot, self.robots_dir)


def job_key(task: int, trial: int) -> str:
    return f"{task}:{trial}"


def system_prompt(cfg: SweepConfig) -> str:
    """The system prompt exactly as ``ghostshell prompt --robot R --format F --mode M --vocabulary V`` prints it
    (with ``cfg.mcp_mounts``, the servers are started once to list their tools)."""
    from host.shell.prompt import render_prompt

    registry = signature_registry(cfg.bot, cfg.vocabulary)
    if not cfg.mcp_mounts:
        return render_prompt(registry, format=cfg.prompt_format, mode=cfg.mode)

    async def with_mounts() -> str:
        from host.mounts import mounted

        async with mounted(cfg.mcp_mounts, registry=registry):
            return render_prompt(registry, format=cfg.prompt_format, mode=cfg.mode)

    return anyio.run(with_mounts)


def replies_for_tasks(blocks: list[Any], tasks: list[int]) -> dict[int, str]:
    """The reply to each of ``tasks`` from ``--replies`` blocks (:func:`host.chat.script.parse_blocks`
    with ``options=("task",)``): either every block has a ``--- task N`` header (tasks not in
    ``tasks`` are ignored, so one file can serve any ``--tasks``), or none has and the blocks answer
    ``tasks`` in order, one each. ValueError (one line) otherwise."""
    headed = [b for b in blocks if b.task is not None]
    if not blocks:
        raise ValueError("holds no reply (blocks are separated by lines '---')")
    if headed and len(headed) != len(blocks):
        first = next(b for b in blocks if b.task is None)
        raise ValueError(f"line {first.line}: a reply without '--- task N' in a file whose other replies name "
                         "their task; name every reply's task, or none (then the replies answer --tasks in order)")
    if not headed:
        if len(blocks) != len(tasks):
            raise ValueError(f"holds {len(blocks)} repl{'y' if len(blocks) == 1 else 'ies'} for {len(tasks)} task(s) "
                             f"({_spec(tasks)}); give one reply per task in that order, or head each reply "
                             "'--- task N'")
        return {t: b.text for t, b in zip(tasks, blocks)}
    by_task: dict[int, str] = {}
    for b in blocks:
        assert b.task is not None
        if b.task in by_task:
            raise ValueError(f"line {b.line}: a second reply for task {b.task}")
        by_task[b.task] = b.text
    missing = [t for t in tasks if t not in by_task]
    if missing:
        raise ValueError(f"has no reply for task(s) {_spec(missing)} (--tasks {_spec(tasks)})")
    return {t: by_task[t] for t in tasks}


def _spec(tasks: list[int]) -> str:
    return ",".join(map(str, tasks)) if len(tasks) <= 8 else f"{tasks[0]}..{tasks[-1]} ({len(tasks)} tasks)"


def provider_of(llm: str) -> str:
    return llm.split(":", 1)[0].lower()


def _instruction(cfg: SweepConfig, task: int) -> str:
    return (ablation_tasks(cfg.bot)[task].instruction if cfg.suite == "ablation" else
            hri_tasks(cfg.bot)[task].instruction)


async def ask(cfg: SweepConfig, task: int, system: str) -> dict[str, Any]:
    """The LLM's reply to one task: ``{"reply", "text", "tool_calls", "first_token_s", "llm_s"}``.
    Raises GhostError when the provider fails (after its retries)."""
    if cfg.llm == GROUND_TRUTH:  # offline: the task's own ground truth, as if a model had written it
        if cfg.suite != "hri":
            raise GhostError("--llm ground-truth answers tasks with a ground truth, not the ablation's patterns")
        truth = hri_tasks(cfg.bot)[task].ground_truth
        return {"reply": truth, "text": truth, "tool_calls": [], "first_token_s": 0.0, "llm_s": 0.0}
    if cfg.llm == SCRIPTED:  # offline: the reply the --replies file gives this task
        if cfg.replies is None or task not in cfg.replies:
            raise GhostError(f"--llm scripted has no reply for task {task}")
        text = cfg.replies[task]
        return {"reply": text, "text": text, "tool_calls": [], "first_token_s": 0.0, "llm_s": 0.0}
    kw: dict[str, Any] = {"base_url": cfg.base_url, "api_key": cfg.api_key, "temperature": cfg.temperature,
                          "max_retries": cfg.max_retries}
    if cfg.native_tools:
        registry = signature_registry(cfg.bot, cfg.vocabulary)
        kw["tools"] = tool_schemas(registry, "anthropic" if provider_of(cfg.llm) == "anthropic" else "openai")
    ghost = make_ghost(cfg.llm, **kw)
    messages = [{"role": "system", "content": system}, {"role": "user", "content": _instruction(cfg, task)}]
    t0 = time.monotonic()
    first: float | None = None
    parts: list[str] = []
    gen = ghost.stream(messages)
    try:
        async for chunk in gen:
            if first is None:
                first = time.monotonic() - t0
            parts.append(chunk)
    finally:
        await gen.aclose()  # type: ignore[attr-defined]
    text = "".join(parts)
    calls: list[dict[str, Any]] = []
    if cfg.native_tools:
        for raw in getattr(ghost, "last_tool_calls", []):
            args: dict[str, Any] = {}
            error = raw.get("error")
            try:
                args = parse_arguments(raw.get("arguments", raw.get("input")))
            except ValueError as err:
                error = f"malformed arguments: {err}"
            calls.append({"name": raw.get("name", ""), "arguments": args, "error": error})
    reply = native_program(text, [ToolCall(c["name"], c["arguments"]) for c in calls if not c["error"]],
                           cfg.native_exec) if cfg.native_tools else text
    return {"reply": reply, "text": text, "tool_calls": calls, "first_token_s": first,
            "llm_s": time.monotonic() - t0}


async def execute(cfg: SweepConfig, program: str, out: Path, label: str) -> dict[str, Any]:
    """Run ``program`` on a fresh lockstep board; the run's outcome and board-measured calls."""
    from host.run.runner import RunOptions, run_program

    opts = RunOptions(program=program, llm="scripted", task_label=label, robot=str(cfg.bot.root),
                      robots_dir=cfg.robots_dir, vocabulary=cfg.vocabulary, mcp_mounts=cfg.mcp_mounts,
                      mode=cfg.mode, strict=True, lockstep=True, out=out, tokens_per_s=cfg.tokens_per_s,
                      plots=cfg.plots)
    t0 = time.monotonic()
    try:
        report = await run_program(opts)
    except Exception as err:  # a board or link failure is this job's result, not the sweep's end
        return {"outcome": "error", "clean": False, "fell": None, "failed_calls": None,
                "error": f"{type(err).__name__}: {err}", "calls": [], "wall_s": round(time.monotonic() - t0, 3)}
    s = report.summary
    failed = s.outcomes.get("failed", 0)
    return {"outcome": s.outcome, "fell": s.fell, "failed_calls": failed,
            "clean": s.outcome == "done" and not s.fell and failed == 0,
            "error": s.extra.get("error"), "max_tilt_deg": s.max_tilt_deg, "duration_s": s.duration_s,
            "calls": [asdict(c) for c in report.calls], "wall_s": round(time.monotonic() - t0, 3)}


async def run_job(cfg: SweepConfig, task: int, trial: int, system: str) -> dict[str, Any]:
    """One (task, trial): ask, score, execute. Returns the results.jsonl record."""
    t0 = time.monotonic()
    rec: dict[str, Any] = {"task": task, "trial": trial, "status": "done", "node": socket.gethostname(),
                           "pid": os.getpid()}
    try:
        rec.update(await ask(cfg, task, system))
    except GhostError as err:
        return {**rec, "status": "llm_error", "error": str(err), "wall_s": round(time.monotonic() - t0, 3)}
    if cfg.suite == "hri":
        t = hri_tasks(cfg.bot)[task]
        res = dsbc_breakdown(t.ground_truth, rec["reply"])
        rec["category"] = t.category
        rec["dsbc"] = res.score
        rec["layers"] = [asdict(layer) for layer in res.layers]
        rec["parse_warnings"] = list(res.warnings)
    else:
        rec["category"] = ablation_tasks(cfg.bot)[task].category
    if cfg.execute:
        run_dir = cfg.out / "runs" / f"task-{task:02d}-trial-{trial}"
        rec["run"] = await execute(cfg, rec["reply"], run_dir, f"task {task} trial {trial}")
        if cfg.suite == "ablation":
            a = ablation_tasks(cfg.bot)[task]
            words = judge_words(cfg.bot)
            pattern = expected_pattern(task, a.expected, words)
            v = judge(pattern, intervals_from_timeline(rec["run"]["calls"]), words)
            rec["pattern"], rec["passed"], rec["verdict"] = pattern, v.passed, v.reason
    rec["wall_s"] = round(time.monotonic() - t0, 3)
    return rec


def load_results(out: Path) -> dict[str, dict[str, Any]]:
    """Finished jobs of an earlier (interrupted) sweep, by job key; a torn last line is ignored."""
    done: dict[str, dict[str, Any]] = {}
    path = out / RESULTS
    if not path.exists():
        return done
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            continue  # the line being written when the sweep was killed
        if rec.get("status") == "done":
            done[job_key(rec["task"], rec["trial"])] = rec
    return done


def _check_config(cfg: SweepConfig) -> None:
    """Refuse to continue a different sweep in ``cfg.out``: same identity and task set, and at least
    as many trials (more trials extends it; the config file then records the new count)."""
    path = cfg.out / CONFIG
    ident = cfg.identity()
    if path.exists():
        try:
            old = json.loads(path.read_text(encoding="utf-8"))
        except json.JSONDecodeError as e:
            raise ValueError(f"{path} is not a sweep's config ({e}); use another --out, or delete it") from None
        old.setdefault("tasks", ident["tasks"])  # written by versions that did not record them
        old.setdefault("robot", ident["robot"])
        old.setdefault("trials", ident["trials"])
        diff = {k: (old.get(k), v) for k, v in ident.items() if k != "trials" and old.get(k) != v}
        if old["trials"] > cfg.trials:
            diff["trials"] = (old["trials"], cfg.trials)
        if diff:
            raise ValueError(f"{cfg.out} holds a different sweep ({diff}); run it with the same --llm/--tasks "
                             f"(and at least --trials {old['trials']}), or use another --out, or delete it")
        if old != ident:
            path.write_text(json.dumps(ident, indent=1) + "\n", encoding="utf-8")
    else:
        path.write_text(json.dumps(ident, indent=1) + "\n", encoding="utf-8")


@dataclass
class SweepProgress:
    """Counts while the sweep runs (for the CLI's progress line)."""

    total: int
    skipped: int
    finished: int = 0
    errors: list[str] = field(default_factory=list)


def pending_jobs(cfg: SweepConfig, done: dict[str, dict[str, Any]]) -> list[tuple[int, int]]:
    return [(t, r) for r in range(cfg.trials) for t in cfg.tasks if job_key(t, r) not in done]


def recorder(sink: IO[str], done: dict[str, dict[str, Any]], progress: SweepProgress,
             on_result: Callable[[dict[str, Any], SweepProgress], None] | None) -> Callable[[dict[str, Any]], None]:
    """What happens to each finished job's record (any backend): appended to the resume log
    ``sink``, kept in ``done`` when it succeeded, counted in ``progress``, then ``on_result``."""

    def record(rec: dict[str, Any]) -> None:
        sink.write(json.dumps(rec, ensure_ascii=False) + "\n")
        sink.flush()
        if rec["status"] == "done":
            done[job_key(rec["task"], rec["trial"])] = rec
        else:
            progress.errors.append(f"task {rec['task']} trial {rec['trial']}: {rec.get('error')}")
        progress.finished += 1
        if on_result is not None:
            on_result(rec, progress)

    return record


async def run_sweep(cfg: SweepConfig, on_result: Callable[[dict[str, Any], SweepProgress], None] | None = None,
                    ) -> list[dict[str, Any]]:
    """Run every pending job, ``cfg.workers`` at a time (more than one: in worker processes,
    :mod:`host.tools.eval.workers`); returns all records of this sweep (earlier ones included) in
    (trial, task) order."""
    cfg.out.mkdir(parents=True, exist_ok=True)
    _check_config(cfg)
    done = load_results(cfg.out)
    jobs = pending_jobs(cfg, done)
    progress = SweepProgress(total=len(cfg.tasks) * cfg.trials, skipped=len(ordered(cfg, done)))
    system = await anyio.to_thread.run_sync(system_prompt, cfg)  # its own event loop when servers are mounted
    with (cfg.out / RESULTS).open("a", encoding="utf-8") as sink:
        record = recorder(sink, done, progress, on_result)
        if cfg.workers > 1 and len(jobs) > 1:
            from host.run.artefacts import warm_up_plotting
            from host.tools.eval.workers import run_in_processes

            async with anyio.create_task_group() as tg:
                # this process only waits meanwhile: set up matplotlib for eval.png now, not (~1 s) after the last job
                tg.start_soon(anyio.to_thread.run_sync, warm_up_plotting)
                await run_in_processes(run_job, cfg, jobs, system, record, cfg.workers)
        else:
            for task, trial in jobs:
                record(await run_job(cfg, task, trial, system))
    return ordered(cfg, done)


def ordered(cfg: SweepConfig, done: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    return [done[job_key(t, r)] for r in range(cfg.trials) for t in cfg.tasks if job_key(t, r) in done]
