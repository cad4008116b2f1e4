"""Whole-body moves outside a program run: "go to this pose and confirm" (``ghostshell pose``/``tour``).

The same road to the servos as a run: a minimum-jerk :func:`robots.motion.transition`
placed on a :class:`~host.motion.mixer.Mixer` and streamed by a
:class:`~host.motion.streamer.FrameStreamer` over a :class:`~host.motion.board_link.BoardFrameLink`
(one frame every ``1 / rate_hz`` s, ``lookahead`` ahead of the board). Telemetry confirms the
frames and, on a lockstep board, moves board time on (the one telemetry driver of a run's pump,
:func:`host.motion.driver.drive`); after the last frame the streamer keeps sending hold frames while
the servos settle.
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Sequence
from dataclasses import dataclass

import anyio
import numpy as np

from host.link import FAULT_BITS, BoardClient
from host.link.errors import LinkError, LinkTimeout, NackError
from host.motion.board_link import BoardFrameLink
from host.motion.driver import drive, realtime_topper
from host.motion.mixer import Mixer
from host.motion.streamer import FrameStreamer
from protocol.messages import FaultFlags, Nack, Telemetry
from robots.motion import JointLimits, transition

__all__ = ["MoveResult", "current_positions", "max_error_deg", "move_to"]

#: lockstep boards: the board time the last move's frames reached (the board runs on to there, so
#: the next move's frames start after it instead of arriving late)
_SENT_UNTIL: weakref.WeakKeyDictionary[BoardClient, int] = weakref.WeakKeyDictionary()


@dataclass(frozen=True)
class MoveResult:
    """Outcome of :func:`move_to`: largest error (deg) and which servo index had it."""

    max_error_deg: float
    worst_index: int
    frames_sent: int
    duration_s: float
    board_time_us: int


def max_error_deg(t: Telemetry, target: Sequence[float] | np.ndarray) -> tuple[float, int]:
    """Largest |position - target| over the servos, in degrees, and its servo index."""
    err = np.abs(np.asarray(t.positions[: len(target)], dtype=float) - np.asarray(target, dtype=float))
    err = np.where(np.isfinite(err), err, np.inf)
    i = int(np.argmax(err))
    return math.degrees(float(err[i])), i


async def _first_telemetry(client: BoardClient, timeout: float) -> Telemetry:
    return await client.wait_for(lambda _t: True, timeout, nudge=True)


async def current_positions(client: BoardClient, timeout: float = 2.0) -> tuple[float, ...]:
    """Measured servo positions from telemetry (advancing a lockstep board a little if needed)."""
    return (await _first_telemetry(client, timeout)).positions


async def move_to(
    client: BoardClient,
    target: Sequence[float],
    limits: JointLimits | None = None,
    *,
    duration_s: float = 1.0,
    rate_hz: float = 100.0,
    tolerance_deg: float = 3.0,
    settle_timeout_s: float = 5.0,
    wall_timeout_s: float = 30.0,
    max_speed: float | None = None,
) -> MoveResult:
    """Min-jerk move of all servos to ``target`` (rad); returns once telemetry shows every servo
    within ``tolerance_deg``. The move lasts at least ``duration_s`` and never asks a servo for
    more than its table speed in ``limits`` (times a margin) or ``max_speed`` (rad/s); without
    ``limits``, those of the robot the board reported in CAPS (found on the robot search path).

    Raises :class:`LinkTimeout` when the servos do not get there within ``settle_timeout_s`` of
    board time after the trajectory ends (the message names the worst servo) or the whole move
    exceeds ``wall_timeout_s``, :class:`NackError` if the board refuses frames, :class:`LinkError`
    on a fault (estop, watchdog).
    """
    if not rate_hz > 0:
        raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
    start = await _first_telemetry(client, wall_timeout_s)
    if start.faults & (FaultFlags.ESTOP | FaultFlags.WATCHDOG_FAULT):
        raise LinkError(f"board is faulted ({FaultFlags(start.faults & FAULT_BITS)!r}); clear it first (estop_clear)")
    q0 = np.asarray(start.positions, dtype=float)
    goal = np.asarray(target, dtype=float)
    servos = tuple(range(len(goal)))
    if limits is None:
        from robots.registry import load_robot

        name = client.caps.robot if client.caps is not None and client.caps.robot else None
        limits = JointLimits.of_robot(load_robot(name) if name else load_robot())
    motion = transition(q0, goal, servos, limits, max_speed=max_speed, min_duration=duration_s)
    link = BoardFrameLink(client)
    period_us = max(1, int(round(1e6 / rate_hz)))
    streamer = FrameStreamer(link, Mixer(q0), period_us=period_us, lookahead_us=max(60_000, 3 * period_us),
                             sparse=link.sparse_frames,
                             start_us=max(start.board_time_us, _SENT_UNTIL.get(client, 0)) if client.lockstep else None)
    seg = streamer.add(motion, label="move_to")
    nacks: list[Nack] = []
    client.on_nack.append(nacks.append)
    goal_reached: list[MoveResult] = []

    def on_report(tel: Telemetry) -> bool:
        if nacks:
            raise NackError(nacks[0])
        if tel.faults & (FaultFlags.ESTOP | FaultFlags.WATCHDOG_FAULT):
            raise LinkError(f"board faulted during the move: {FaultFlags(tel.faults & FAULT_BITS)!r}")
        end = streamer.times(seg).end
        if end is None:
            return False
        err, idx = max_error_deg(tel, goal)
        if err <= tolerance_deg:
            goal_reached.append(MoveResult(err, idx, streamer.frames_sent, motion.duration, tel.board_time_us))
            return True
        if tel.board_time_us >= int((end + settle_timeout_s) * 1e6):
            raise LinkTimeout(f"servos not within {tolerance_deg} deg of the target {settle_timeout_s} s after the "
                              f"move: largest error {err:.2f} deg on servo index {idx}")
        return False

    try:
        with anyio.fail_after(wall_timeout_s):
            async with anyio.create_task_group() as tg:
                if not client.lockstep:
                    tg.start_soon(realtime_topper, streamer)
                await streamer.top_up(start.board_time_us if client.lockstep else None)
                await drive(streamer, client.telemetry(maxsize=256), lockstep=client.lockstep, on_report=on_report)
                tg.cancel_scope.cancel()
    except TimeoutError:
        raise LinkTimeout(f"move did not finish within {wall_timeout_s} s of wall time") from None
    except BaseExceptionGroup as group:  # the move's own error (a NACK, a fault), not a group: callers catch LinkError
        link_errors = [e for e in group.exceptions if isinstance(e, LinkError)]
        if len(link_errors) == len(group.exceptions) == 1:
            raise link_errors[0] from None
        raise
    finally:
        client.on_nack.remove(nacks.append)
        _SENT_UNTIL[client] = streamer.first_free_us
    if not goal_reached:
        raise LinkError("telemetry stopped before the move was confirmed")
    return goal_reached[0]

