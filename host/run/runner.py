"""One run end to end: board on a pty (or a given port), link, robot runtime, shell, LLM, artefacts.

Everything is real: the board is ``python -m firmware_sim`` in a subprocess, the
link is pyserial over its pty, the physics is MuJoCo stepping at the control
rate. In lockstep the board clock is virtual and only moves as far as the host
streams frames, so the whole run (the LLM's token pacing included) is timed on
the board clock; in realtime both follow the wall clock.

A run is a :class:`~host.run.robot_session.RobotSession` with a single turn whose
artefacts go straight into ``out``.

Stops (:mod:`host.run.stops`): with ``RunOptions.handle_signals`` (the CLI) the first SIGINT or
SIGTERM interrupts the turn, the robot goes to its rest pose and every artefact is written
(``RunReport.stop``); a second one (or one during start-up) cancels the run at once and
:func:`run_program` raises :class:`~host.run.stops.Interrupted` after writing summary.json and
timeline.json (:func:`ended_report` gives that report). A bound (``max_board_s``, ``max_log_mb``)
stops the run like a first signal, with outcome ``limit``.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import NoReturn

import anyio
import anyio.to_thread

from host.ghost import make_ghost
from host.link.errors import LinkError
from host.run import artefacts
from host.runtime.robot_runtime import RobotRuntime
from host.run.pump import HISTORY, SETTLE_CHECKPOINTS, TELEMETRY_SILENCE_S
from host.run.options import SessionOptions
from host.run.robot_session import RobotSession, TurnResult
from host.run.stops import StopReason, StopSignals
from host.shell import Shell

log = logging.getLogger("host.run")

__all__ = ["HISTORY", "SETTLE_CHECKPOINTS", "TELEMETRY_SILENCE_S", "RunOptions", "RunReport", "ended_report", "run_program"]


@dataclass
class RunOptions(SessionOptions):
    """What to run and how (the ``ghostshell run`` flags): the session's options (:class:`SessionOptions`:
    robot, board, link, shell, bounds) and the run's own below."""

    program: str | None = None  # function tokens to replay (scripted LLM)
    prompt: str | None = None  # an instruction for a real LLM
    llm: str = "scripted"
    task_label: str = "program"  # the run's one turn (SessionOptions.task_label, whose default is "session")
    tokens_per_s: float = 30.0
    seed: int = 0
    llm_base_url: str | None = None
    llm_api_key: str | None = None
    interrupt_at: float | None = None  # board seconds after the run starts: external interruption
    settle_s: float = 0.5
    buffer_response: bool = False  # wait for the whole LLM response before executing (the non-streaming baseline)
    live: bool = False  # draw the live channel view (on a terminal)
    handle_signals: bool = False  # SIGINT/SIGTERM interrupt the run (the CLI; main thread only)


@dataclass
class RunReport(TurnResult):
    """What a run produced (also written to the run folder): its one turn (:class:`TurnResult`) and how
    it stopped."""

    stop: StopReason | None = None  # why the run stopped early (a signal, a bound), else None
    rested: bool | None = None  # after a stop: the robot reached its rest pose (None: no stop, or it came after the turn)

    @classmethod
    def of(cls, turn: TurnResult, stop: StopReason | None = None, rested: bool | None = None) -> RunReport:
        """The report of ``turn``."""
        return cls(**{f.name: getattr(turn, f.name) for f in fields(TurnResult)}, stop=stop, rested=rested)


async def run_program(opts: RunOptions, on_start: Callable[[Shell, RobotRuntime], None] | None = None) -> RunReport:
    """Run ``opts`` end to end and write the artefacts to ``opts.out``.

    A run that ends on a :class:`LinkError` after the session came up (the board latched its
    watchdog fault, fell silent, a request timed out) still writes its artefacts
    (:meth:`RobotSession.ended_turn`: ``summary.json`` with ``outcome`` ``link_lost``, the calls
    as far as they got, ``extra.faults``) and then raises that same error; :func:`ended_report`
    gives the :class:`RunReport` it wrote.
    """
    session = RobotSession(opts)
    signals = StopSignals(session.request_stop, session.abort_cleanups) if opts.handle_signals else None
    rested: bool | None = None
    turn: TurnResult | None = None
    written = False
    # One guard over the session and the writing of its artefacts: between two guards a signal met the
    # event loop's own SIGINT handler and cancelled the run before anything was written.
    async with (signals.guard() if signals is not None else contextlib.nullcontext()):
        try:
            async with session:
                messages = [{"role": "system", "content": session.prompt(format="xml")},
                            {"role": "user", "content": opts.prompt or ""}]
                if opts.llm == "scripted":  # paced on the board clock, so lockstep runs are reproducible
                    ghost = make_ghost("scripted", program=opts.program, tokens_per_s=opts.tokens_per_s,
                                       seed=opts.seed, sleep=session.pacer())
                else:
                    ghost = make_ghost(opts.llm, base_url=opts.llm_base_url, api_key=opts.llm_api_key)
                if on_start is not None:
                    on_start(session.shell, session.runtime)
                if opts.live:
                    from host.run.live import live_view

                    session.background().start_soon(live_view, session.shell, session.runtime, opts.task_label)
                turn = await session.run_turn(ghost.stream(messages), label=opts.task_label, out=opts.out,
                                              hold=opts.llm != "scripted", buffer=opts.buffer_response,
                                              interrupt_after=opts.interrupt_at, settle_s=opts.settle_s,
                                              write=False)
                if session.stop is not None:  # a signal or a bound cut the run: end at the rest pose
                    rested = await session.go_to_rest()
                    turn.summary.extra.setdefault("stopped", {})["rest_pose"] = (
                        session.robot.rest_pose if rested else None)
                    timing = turn.summary.extra.get("timing")
                    if isinstance(timing, dict):  # the deadline may have cut the rest pose after the turn ended
                        timing["stop_overdue"] = session.stop_overdue
                write = session.writer(turn, opts.task_label)  # snapshot now, plot after the board stopped
        except LinkError as exc:
            if signals is None or signals.forced is None:
                _end_on_link_error(session, exc, opts)
                raise
            # else the cancellation broke the link: not a loss; reported as the interruption it was, below
        else:
            # The artefacts of a finished turn are always written whole (plotting takes a fraction of a
            # second, in a worker thread: other runs in this loop go on meanwhile). A first signal now has
            # no turn left to interrupt (session.request_stop records it; the command exits 130 and says
            # the turn had ended); a second one waits for the writing too.
            with anyio.CancelScope(shield=True):
                await anyio.to_thread.run_sync(write)
            written = True
    if signals is not None and signals.forced is not None and not written:  # at once: the JSON files, then out
        _raise_forced(session, signals, turn, opts)
    assert turn is not None  # the session ran its turn (every other way out raised above)
    stop = signals.reported(session.stop) if signals is not None else session.stop
    return RunReport.of(turn, stop, rested)


def _raise_forced(session: RobotSession, signals: StopSignals, turn: TurnResult | None, opts: RunOptions) -> NoReturn:
    """A forced stop (the second signal): summary.json and timeline.json of what ran, then
    :class:`Interrupted` carrying their :class:`RunReport`."""
    interrupted = signals.interrupted()
    stop = interrupted.stop
    if turn is not None:  # the turn itself had ended (the second signal came while going to rest)
        turn.summary.outcome = "interrupted"
        turn.summary.extra["stopped"] = {**interrupted.stopped_extra(), "rest_pose": None}
        ended: TurnResult | None = turn
    else:
        ended = session.ended_turn(interrupted, opts.task_label, opts.out)
    if ended is not None:
        session.write_now(ended, opts.task_label, plots=False)
        setattr(interrupted, _REPORT_ATTR, RunReport.of(ended, stop))
    raise interrupted


def _end_on_link_error(session: RobotSession, exc: LinkError, opts: RunOptions) -> None:
    """Write the report of a run a link error ended (see :func:`run_program`), if anything ran."""
    ended = session.ended_turn(exc, opts.task_label, opts.out)
    if ended is None:  # the session never came up: nothing ran, nothing to report
        return
    log.info("the run ended on a link error; writing its artefacts to %s", opts.out)
    session.write_now(ended, opts.task_label)  # the board has stopped: its fault report is in
    setattr(exc, _REPORT_ATTR, RunReport.of(ended))


_REPORT_ATTR = "ghostshell_run_report"


def ended_report(exc: BaseException) -> RunReport | None:
    """The report :func:`run_program` wrote before re-raising ``exc`` (a run ended by a link
    error), or None when it wrote nothing."""
    report = getattr(exc, _REPORT_ATTR, None)
    return report if isinstance(report, RunReport) else None
