"""A turn's ``summary.json`` (:class:`host.run.artefacts.Summary`), from what the session measured.

:class:`TurnSummaries` holds what does not change in a session (the robot, its options, vocabulary,
the ground-truth recorder, the scene and clock getters) and builds a summary for one turn
(:meth:`TurnSummaries.summary`) or for a session whose link failed before it had a runtime
(:meth:`TurnSummaries.bare`). The fields and their units are :class:`host.run.artefacts.Summary`'s;
``extra`` is documented in docs/guides/running.md.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from host.run import artefacts
from host.run.events import Event, has_fallen
from host.run.options import SessionOptions
from host.run.stops import Interrupted, StopReason
from host.shell.timeline import RunResult
from robots.description import Robot

if TYPE_CHECKING:
    from host.link import BoardClient
    from host.motion.streamer import FrameStreamer
    from host.run.pump import Recorder
    from host.runtime.robot_runtime import RobotRuntime

__all__ = ["TurnSummaries", "TurnView", "board_calls", "pose", "fell"]


@dataclass
class TurnView:
    """What a summary needs of one turn: its result, calls, events and where it started.

    ``board_t0`` board seconds at the turn's start; ``base_start`` the ground-truth report before it
    (``(t, pos, quat)`` or None); ``tilt_from`` the recorder's index of the turn's first base report."""

    label: str
    result: RunResult
    calls: list[artefacts.BoardCall]
    board_t0: float
    base_start: Any
    tilt_from: int
    captures: list[Path]
    events: list[Event]
    interrupted_by: Event | None


def pose(b: Any) -> list[float] | None:
    """A ground-truth report's base pose as ``[x m, y m, yaw deg]``; None without a report."""
    return [round(b[1][0], 4), round(b[1][1], 4), round(artefacts.yaw_deg(b[2]), 2)] if b else None


def fell(robot: Robot, tilt: float, z: float | None, z0: float | None) -> bool:
    """Whether ``robot`` fell (:func:`host.run.events.has_fallen`): only a floating base can (a fixed one
    stays where its MJCF puts it)."""
    return robot.base.floating and has_fallen(tilt, z, z0)


def board_calls(result: RunResult, runtime: RobotRuntime | None) -> list[artefacts.BoardCall]:
    """The turn's calls on the board clock: the board-measured start/end where the runtime has them
    (``runtime.board_times``), else the shell's clock offset by ``result.t0`` (seconds)."""
    calls = []
    board_times = runtime.board_times if runtime is not None else {}
    for r in result.timeline:
        measured = board_times.get(r.path, [None, None])
        start = measured[0] if measured[0] is not None else (None if r.start is None else result.t0 + r.start)
        end = measured[1] if measured[1] is not None else (None if r.end is None else result.t0 + r.end)
        calls.append(artefacts.BoardCall(r.function, r.channel, dict(r.args), r.path, start, end, r.outcome,
                                         r.error, r.persistent, r.ended_by))
    return calls


def _link_stats(client: BoardClient | None, streamer: FrameStreamer) -> dict[str, Any]:
    tel = client.latest_telemetry if client is not None else None
    # frames_sent: the SERVO_FRAMEs the link wrote by the turn's end (the host frame log's count then; a
    # realtime streamer holds the pose until the link closes, so the log may end a few frames later),
    # not the streamer's grid frames
    return {"frames_sent": client.stats.servo_frames_sent if client else streamer.frames_sent,
            "frames_skipped": streamer.frames_skipped, "late": tel.late_count if tel else None,
            "dropped": tel.dropped_count if tel else None,
            "frame_nacks": client.stats.frame_nacks if client else None,
            "decode_errors": client.stats.decode_errors if client else None,
            "retries": client.stats.retries if client else None,
            "seq_gaps": client.stats.seq_gaps if client else None,
            "watchdog_holds": client.fanout.watchdog_holds if client else None,
            **({"last_decode_error": client.stats.last_decode_error}
               if client and client.stats.last_decode_error else {})}


class TurnSummaries:
    """Builds the summaries of one session's turns (see the module docstring).

    ``scene()`` is the scene's ground truth now (``{"name", "objects", "toppled"}``); ``clock()`` is
    ``"lockstep"`` or ``"realtime"``."""

    def __init__(self, robot: Robot, opts: SessionOptions, vocabulary: str, rec: Recorder,
                 scene: Callable[[], dict[str, Any]], clock: Callable[[], str]) -> None:
        self.robot, self.opts, self.vocabulary, self.rec = robot, opts, vocabulary, rec
        self._scene, self._clock = scene, clock

    def _identity(self) -> dict[str, Any]:
        return {"clock": self._clock(), "robot": self.robot.name, "robot_folder": str(self.robot.root),
                "vocabulary": self.vocabulary, "mode": self.opts.mode}

    def summary(self, turn: TurnView, *, streamer: FrameStreamer, client: BoardClient | None,
                stop: StopReason | None, timing: dict[str, Any],
                link_error: BaseException | None = None) -> artefacts.Summary:
        """The summary of ``turn``: its outcome (done, failed, interrupted, link_lost, or the stop's),
        the base's start/end pose and tilt from the ground truth, first-action latency (ms), link counts,
        timing health (``timing``: :meth:`host.run.robot_session.RobotSession.timing`)."""
        opts, rec, result, calls = self.opts, self.rec, turn.result, turn.calls
        cut_short = link_error is not None
        base = list(rec.base)[turn.tilt_from:] if turn.tilt_from < len(rec.base) else list(rec.base)[-1:]
        max_tilt = max((artefacts.tilt_deg(b[2]) for b in base), default=0.0)
        b0 = turn.base_start or (base[0] if base else None)
        b1 = base[-1] if base else None
        starts = [c.start for c in calls if c.start is not None and c.function not in ("wait", "async")]
        first = (min(starts) - turn.board_t0) * 1000 if starts else None
        counts = artefacts.count_outcomes(calls)
        board_fault = streamer.failure if streamer.failure is not link_error else None
        failed = counts.get("failed", 0) or result.error is not None or result.save_failures or board_fault is not None
        outcome = "failed" if board_fault is not None else ("interrupted" if result.interrupted else
                                                            ("failed" if failed else "done"))
        stopped: dict[str, Any] = {}
        if isinstance(link_error, Interrupted):  # a signal cancelled the work at once: not a link error
            outcome, stopped, link_error = "interrupted", {"stopped": link_error.stopped_extra()}, None
        elif link_error is not None:
            outcome = "link_lost"
        elif stop is not None and board_fault is None:
            outcome, stopped = stop.outcome, {"stopped": stop.as_dict()}
        has_fallen_ = fell(self.robot, max_tilt, min((b[1][2] for b in base), default=None), rec.base_z0)
        tel = client.latest_telemetry if client is not None else None
        stats = _link_stats(client, streamer)
        end_t = rec.t[-1] if rec.t else turn.board_t0
        if cut_short and tel is not None:  # a stop at once, a loss: the board time the link received, which the
            end_t = max(end_t, tel.board_time_us * 1e-6)  # pump may not have handled yet
        host_detected: dict[str, Any] = {"decode_errors": stats["decode_errors"], "frame_nacks": stats["frame_nacks"],
                                         "request_retries": stats["retries"], "seq_gaps": stats["seq_gaps"]}
        if link_error is not None:
            host_detected["link_lost"] = str(link_error)
            host_detected["last_report_board_s"] = rec.t[-1] if rec.t else None
        return artefacts.Summary(
            task=turn.label, outcome=outcome, fell=has_fallen_ if base else None, base_start=pose(b0),
            base_end=pose(b1), max_tilt_deg=round(max_tilt, 2) if base else None,
            first_action_latency_ms=None if first is None else round(first, 1),
            outcomes=counts, duration_s=round(end_t - turn.board_t0, 3),
            final_joints_deg=artefacts.joint_angles_deg(self.robot.servos.names, tel.positions if tel is not None
                                                        else (rec.q[-1] if rec.q else None)),
            extra={**self._identity(), "error": None if result.error is None else str(result.error),
                   **({"link_error": str(link_error)} if link_error is not None else {}),
                   **stopped,
                   **({"board_fault": str(board_fault)} if board_fault is not None else {}),
                   "observations": [str(o) for o in result.observations], "link": stats,
                   # SIM_STATE reports the base pose and tilt came from (0: both are unknown, not zero)
                   "base_reports": len(base),
                   "events": [str(e) for e in turn.events],
                   **({"interrupted_by": str(turn.interrupted_by)} if turn.interrupted_by is not None else {}),
                   "captures": [p.name for p in turn.captures], "scene": self._scene(),
                   "timing": timing,
                   **({"faults": {"host_detected": host_detected}} if opts.faults else {})})

    def bare(self, error: BaseException, label: str, client: BoardClient | None) -> artefacts.Summary:
        """The summary of a session whose link failed (or a signal stopped it) before the runtime existed."""
        stats = client.stats if client is not None else None
        host_detected = {"decode_errors": stats.decode_errors if stats else None,
                         "frame_nacks": stats.frame_nacks if stats else None,
                         "request_retries": stats.retries if stats else None,
                         "seq_gaps": stats.seq_gaps if stats else None, "link_lost": str(error)}
        stopped = isinstance(error, Interrupted)
        return artefacts.Summary(
            task=label, outcome="interrupted" if stopped else "link_lost", fell=None, base_start=None,
            base_end=None, max_tilt_deg=None, first_action_latency_ms=None, outcomes=artefacts.count_outcomes([]),
            extra={**self._identity(), "error": None,
                   **({"stopped": error.stopped_extra()} if isinstance(error, Interrupted)
                      else {"link_error": str(error)}),
                   "observations": [],
                   "link": {}, "captures": [], "scene": self._scene(),
                   **({"faults": {"host_detected": host_detected}} if self.opts.faults and not stopped else {})})
