"""One run end to end: board on a pty (or a given port), link, CoCo runtime, shell, LLM, artefacts.

Everything is real: the board is ``python -m firmware_sim`` in a subprocess, the
link is pyserial over its pty, the physics is MuJoCo stepping at the control
rate. In lockstep the board clock is virtual and only moves as far as the host
streams frames, so the whole run (the LLM's token pacing included) is timed on
the board clock; in realtime both follow the wall clock.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections import deque
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import anyio
import anyio.lowlevel
import numpy as np

from host.coco.binding import coco_registry
from host.coco.link import ClientLink
from host.coco.runtime import CocoRuntime
from host.ghost import GhostError, make_ghost
from host.link.board_process import BoardProcess, start_board
from host.link.client import BoardClient
from host.link.errors import LinkError
from host.run import artefacts
from host.shell import Shell
from host.shell.prompt import render_prompt
from host.shell.timeline import RunResult
from protocol.linkspec import LinkSpec, parse_link_spec
from robots.coco import load_poses, load_servo_table
from robots.coco.motions import transition

log = logging.getLogger("host.run")

HISTORY = 360_000  # telemetry samples kept for the plots (2 h at 50 Hz); older ones are dropped


@dataclass
class RunOptions:
    """What to run and how (the ``ghostshell run`` flags)."""

    program: str | None = None  # function tokens to replay (scripted LLM)
    prompt: str | None = None  # an instruction for a real LLM
    llm: str = "scripted"
    task_label: str = "program"
    vocabulary: str = "paper"
    mode: str = "async-first"
    strict: bool = True
    lockstep: bool = False
    link: str | LinkSpec = "pty"  # a link spec (protocol.linkspec)
    emulate_board: bool | None = None  # start the emulated board on `link` first; None: only where implied (pty, can:slcan:pty)
    baud: int = 115200
    out: Path = Path("runs/latest")
    tokens_per_s: float = 30.0
    seed: int = 0
    llm_base_url: str | None = None
    llm_api_key: str | None = None
    interrupt_at: float | None = None  # board seconds after the run starts: external interruption
    settle_s: float = 0.5
    buffer_response: bool = False  # wait for the whole LLM response before executing (the non-streaming baseline)
    start_pose: str = "stand"
    live: bool = False  # draw the live channel view (on a terminal)


@dataclass
class RunReport:
    """What a run produced (also written to the run folder)."""

    result: RunResult
    calls: list[artefacts.BoardCall]
    summary: artefacts.Summary
    out: Path
    token_times: list[tuple[float, str]] = field(default_factory=list)
    board_t0: float = 0.0


class _Recorder:
    """Bounded telemetry/ground-truth history for plots and the summary."""

    def __init__(self) -> None:
        self.t: deque[float] = deque(maxlen=HISTORY)
        self.q: deque[tuple[float, ...]] = deque(maxlen=HISTORY)
        self.base: deque[tuple[float, tuple[float, float, float], tuple[float, float, float, float]]] = deque(maxlen=HISTORY)
        self.max_tilt = 0.0
        self.last_rx = time.monotonic()  # wall time of the last report (for the silence watchdog)

    def add(self, client: BoardClient, tel: Any) -> None:
        self.t.append(tel.board_time_us * 1e-6)
        self.q.append(tel.positions)
        s = client.latest_sim_state
        if s is not None:
            self.base.append((s.board_time_us * 1e-6, s.base_pos, s.base_quat))
            self.max_tilt = max(self.max_tilt, artefacts.tilt_deg(s.base_quat))


#: checkpoints the lockstep pump yields before topping up, so that everything the last
#: telemetry woke (token pacing, dispatch, new segments) is placed before board time moves on
SETTLE_CHECKPOINTS = 32
#: wall seconds without telemetry after which a run fails (the board died or the link hung)
TELEMETRY_SILENCE_S = 10.0


async def _pump(client: BoardClient, runtime: CocoRuntime, rec: _Recorder) -> None:
    """Telemetry -> confirmations, top-ups and the history.

    In lockstep each report is handled in order and the board is advanced only
    from that report's time, after the host has reacted to it, so board time
    steps with the host instead of running ahead of it.
    """
    lockstep = client.lockstep
    async for tel in client.telemetry(maxsize=1024):
        rec.last_rx = time.monotonic()
        runtime.streamer.on_telemetry(tel)
        rec.add(client, tel)
        if lockstep:
            for _ in range(SETTLE_CHECKPOINTS):
                await anyio.lowlevel.checkpoint()
            await runtime.streamer.top_up(tel.board_time_us)
        else:
            await runtime.streamer.top_up()


async def _silence_watchdog(runtime: CocoRuntime, rec: _Recorder) -> None:
    """Fail the run when the board stops reporting (it died, or the link hung)."""
    while True:
        await anyio.sleep(1.0)
        if runtime.streamer.held:  # a held lockstep board is silent on purpose (waiting for the LLM)
            rec.last_rx = time.monotonic()
        elif time.monotonic() - rec.last_rx > TELEMETRY_SILENCE_S:
            raise LinkError(f"no telemetry from the board for {TELEMETRY_SILENCE_S:g} s; giving up the run")


async def _realtime_topper(runtime: CocoRuntime) -> None:
    period = runtime.streamer.period_us * 1e-6
    while True:
        await runtime.streamer.top_up()
        await anyio.sleep(period)


async def _timed_chunks(stream: AsyncIterator[str], clock: Callable[[], float], log_to: list[tuple[float, str]],
                        hold: Callable[[], contextlib.AbstractAsyncContextManager[None]] | None = None,
                        ) -> AsyncIterator[str]:
    """The LLM's chunks, each logged with its board arrival time.

    With ``hold`` (a real LLM on a lockstep board) the board clock stands still
    while the host waits for the next chunk, so network latency does not turn
    into board time.
    """
    while True:
        try:
            if hold is None:
                chunk = await anext(stream)
            else:
                async with hold():
                    chunk = await anext(stream)
        except StopAsyncIteration:
            return
        log_to.append((clock(), chunk))
        yield chunk


async def _buffered(stream: AsyncIterator[str]) -> AsyncIterator[str]:
    """The whole response at once, after the last chunk arrived (no streaming execution)."""
    yield "".join([chunk async for chunk in stream])


class _BoardPacer:
    """A sleep for the scripted LLM on the board clock, against absolute deadlines.

    Board time is observed in telemetry steps (20 ms at 50 Hz); sleeping each gap
    from "now" would round every gap up and slow the token rate, so the gaps are
    summed from the first call and each wait targets the running deadline.
    """

    def __init__(self, runtime: CocoRuntime) -> None:
        self.runtime = runtime
        self.deadline_us: int | None = None

    async def __call__(self, seconds: float) -> None:
        streamer = self.runtime.streamer
        if self.deadline_us is None:
            self.deadline_us = streamer.board_now_us()
        self.deadline_us += int(round(seconds * 1e6))
        await streamer.wait_board_time(self.deadline_us)


async def _go_to_pose(runtime: CocoRuntime, pose: str) -> None:
    """Move every servo smoothly to a named pose before the program starts."""
    target = np.asarray(load_poses()[pose])
    start = runtime.streamer.planned_targets()
    servos = tuple(range(len(target)))
    seg = runtime.streamer.add(transition(start, target, servos), label=f"prepare:{pose}")
    await runtime.streamer.wait_ended(seg)


async def run_program(opts: RunOptions, on_start: Callable[[Shell, CocoRuntime], None] | None = None) -> RunReport:
    """Run ``opts`` end to end and write the artefacts to ``opts.out``."""
    out = opts.out
    out.mkdir(parents=True, exist_ok=True)
    board: BoardProcess | None = None
    spec = parse_link_spec(opts.link)
    target = spec
    emulate = opts.emulate_board if opts.emulate_board is not None else spec.implies_emulated_board
    if spec.implies_emulated_board and not emulate:
        raise LinkError(f"{spec} is a link the emulated board creates: it cannot be used without starting the board")
    # frame logs: JSON Lines on serial; python-can's candump format (.log) on CAN
    log_suffix = ".log" if spec.kind == "can" else ".jsonl"
    if emulate and spec.kind == "can" and spec.interface == "virtual":
        raise LinkError(f"{spec}: python-can's virtual bus exists inside one process, so an emulated board "
                        "started as a subprocess cannot join it; use can:slcan:pty, or can:socketcan:vcan0 "
                        "with --emulate-board (the virtual bus is for in-process tests)")
    if emulate:
        board_args = ["--lockstep" if opts.lockstep else "--realtime", "--log", str(out / f"board_frames{log_suffix}")]
        board = start_board(board_args, out / "board.stderr", link=spec)
        target = board.spec
    rec = _Recorder()
    token_times: list[tuple[float, str]] = []
    try:
        async with await BoardClient.connect(target, baud=opts.baud, log_path=out / f"host_frames{log_suffix}") as client:
            link = ClientLink(client)
            if client.latest_telemetry is None and client.lockstep:
                await client.advance(client.board_now_estimate() + 20_000)  # let a lockstep board report once
            tel = await client.wait_for(lambda t: True, timeout=10)
            runtime = CocoRuntime(link, out, initial=np.asarray(tel.positions))
            registry = coco_registry(runtime, opts.vocabulary)
            shell = Shell(registry, mode=opts.mode, strict=opts.strict, clock=runtime.board_now_s)
            result: RunResult | None = None
            async with anyio.create_task_group() as tg:
                tg.start_soon(_pump, client, runtime, rec)
                tg.start_soon(_silence_watchdog, runtime, rec)
                if not client.lockstep:
                    tg.start_soon(_realtime_topper, runtime)
                await runtime.streamer.top_up()
                await _go_to_pose(runtime, opts.start_pose)
                base_start = rec.base[-1] if rec.base else None
                messages = [{"role": "system", "content": render_prompt(registry, format="xml", mode=opts.mode)},
                            {"role": "user", "content": opts.prompt or ""}]
                if opts.llm == "scripted":  # paced on the board clock, so lockstep runs are reproducible
                    ghost = make_ghost("scripted", program=opts.program, tokens_per_s=opts.tokens_per_s,
                                       seed=opts.seed, sleep=_BoardPacer(runtime))
                else:
                    ghost = make_ghost(opts.llm, base_url=opts.llm_base_url, api_key=opts.llm_api_key)
                board_t0 = runtime.board_now_s()
                if on_start is not None:
                    on_start(shell, runtime)
                if opts.live:
                    from host.run.live import live_view

                    tg.start_soon(live_view, shell, runtime, opts.task_label)
                if opts.interrupt_at is not None:
                    tg.start_soon(_interrupter, shell, runtime, board_t0 + opts.interrupt_at)
                hold = runtime.streamer.hold if opts.llm != "scripted" else None
                chunks = _timed_chunks(ghost.stream(messages), runtime.board_now_s, token_times, hold)
                result = await shell.run(_buffered(chunks) if opts.buffer_response else chunks)
                await runtime.sleep(opts.settle_s)
                tg.cancel_scope.cancel()
            assert result is not None
            stats = {"frames_sent": runtime.streamer.frames_sent, "late": client.latest_telemetry.late_count
                     if client.latest_telemetry else None,
                     "dropped": client.latest_telemetry.dropped_count if client.latest_telemetry else None,
                     "frame_nacks": client.stats.frame_nacks, "decode_errors": client.stats.decode_errors}
    except BaseExceptionGroup as group:  # one task's failure cancels the rest: report the cause
        cause = _first_cause(group)
        if cause is None:
            raise
        raise cause from group
    finally:
        if board is not None:
            board.stop()
    return _write(opts, result, runtime, rec, token_times, board_t0, base_start, stats)


def _first_cause(group: BaseExceptionGroup) -> Exception | None:
    """The link or LLM error behind a task group's failure, if that is what it was."""
    for exc in group.exceptions:
        if isinstance(exc, BaseExceptionGroup):
            found = _first_cause(exc)
            if found is not None:
                return found
        elif isinstance(exc, (LinkError, GhostError)):
            return exc
    return None


async def _interrupter(shell: Shell, runtime: CocoRuntime, at_s: float) -> None:
    await runtime.streamer.wait_board_time(int(at_s * 1e6))
    shell.interrupt()


def _board_calls(result: RunResult, runtime: CocoRuntime) -> list[artefacts.BoardCall]:
    calls = []
    for r in result.timeline:
        measured = runtime.board_times.get(r.path, [None, None])
        start = measured[0] if measured[0] is not None else (None if r.start is None else result.t0 + r.start)
        end = measured[1] if measured[1] is not None else (None if r.end is None else result.t0 + r.end)
        calls.append(artefacts.BoardCall(r.function, r.channel, dict(r.args), r.path, start, end, r.outcome,
                                         r.error, r.persistent))
    return calls


def _write(opts: RunOptions, result: RunResult, runtime: CocoRuntime, rec: _Recorder,
           token_times: list[tuple[float, str]], board_t0: float, base_start: Any, stats: dict[str, Any]) -> RunReport:
    out = opts.out
    calls = _board_calls(result, runtime)
    artefacts.write_timeline_json(out / "timeline.json", calls, t0=board_t0)
    artefacts.plot_timeline(out / "timeline.png", calls, title=f"{opts.task_label}: calls on the board clock")
    if rec.t:
        times = np.asarray(rec.t)
        names = load_servo_table().names
        sent = runtime.streamer.history
        targets = (np.asarray([t for t, _ in sent]) * 1e-6, np.asarray([q for _, q in sent])) if sent else None
        artefacts.plot_joints(out / "joints.png", times, np.asarray(rec.q), names, targets)
    b0 = base_start or (rec.base[0] if rec.base else None)
    b1 = rec.base[-1] if rec.base else None
    pose = (lambda b: [round(b[1][0], 4), round(b[1][1], 4), round(artefacts.yaw_deg(b[2]), 2)] if b else [0.0, 0.0, 0.0])
    starts = [c.start for c in calls if c.start is not None and c.function not in ("wait", "async")]
    first = (min(starts) - board_t0) * 1000 if starts else None
    counts = artefacts.count_outcomes(calls)
    failed = counts.get("failed", 0) or result.error is not None
    outcome = "interrupted" if result.interrupted else ("failed" if failed else "done")
    fell = rec.max_tilt > 45.0 or bool(rec.base and min(b[1][2] for b in rec.base) < 0.03)
    summary = artefacts.Summary(
        task=opts.task_label, outcome=outcome, fell=fell, base_start=pose(b0), base_end=pose(b1),
        max_tilt_deg=round(rec.max_tilt, 2), first_action_latency_ms=None if first is None else round(first, 1),
        outcomes=counts, duration_s=round((rec.t[-1] if rec.t else board_t0) - board_t0, 3),
        extra={"clock": "lockstep" if opts.lockstep else "realtime", "vocabulary": opts.vocabulary,
               "mode": opts.mode, "error": None if result.error is None else str(result.error),
               "observations": [str(o) for o in result.observations], "link": stats,
               "captures": [p.name for p in runtime.captures]})
    artefacts.write_summary_json(out / "summary.json", summary)
    return RunReport(result, calls, summary, out, token_times, board_t0)

