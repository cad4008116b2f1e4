"""Streaming a trajectory to the board as timed frames, and "go to this pose and confirm".

Frames carry apply-at times on the board clock: ``t0 = board_now_estimate() +
lookahead`` then one frame per trajectory sample. They are sent at most ``lead``
ahead of the board's clock, so the jitter buffer never holds more than
``lead * rate`` frames. On a realtime board the host paces itself on its synced
clock estimate; on a lockstep board the board's clock only moves as far as the
frames cover, so the host paces on the board time that telemetry reports, and
after the last frame sends ADVANCE to let the servos settle.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from host.link.client import ALL_SERVOS, FAULT_BITS, BoardClient
from host.link.errors import LinkError, LinkTimeout, NackError
from host.motion.trajectory import min_jerk
from protocol.messages import FaultFlags, Nack, ServoFrame, Telemetry

__all__ = ["MoveResult", "current_positions", "max_error_deg", "move_to", "stream_trajectory"]


@dataclass(frozen=True)
class MoveResult:
    """Outcome of :func:`move_to`: largest error (deg) and which servo index had it."""

    max_error_deg: float
    worst_index: int
    frames_sent: int
    duration_s: float
    board_time_us: int


def max_error_deg(t: Telemetry, target: Sequence[float]) -> tuple[float, int]:
    """Largest |position - target| over the servos, in degrees, and its servo index."""
    err = np.abs(np.asarray(t.positions[: len(target)], dtype=float) - np.asarray(target, dtype=float))
    err = np.where(np.isfinite(err), err, np.inf)
    i = int(np.argmax(err))
    return math.degrees(float(err[i])), i


async def _first_telemetry(client: BoardClient, timeout: float) -> Telemetry:
    if client.latest_telemetry is not None:
        return client.latest_telemetry
    if client.lockstep:
        tick = 1_000_000 // max(1, client.caps.control_rate_hz if client.caps else 500)
        rate = client.caps.telemetry_rate_hz if client.caps else 50
        await client.advance(client.board_now_estimate() + max(tick, 1_000_000 // max(1, rate)))
    return await client.wait_for(lambda _t: True, timeout)


async def current_positions(client: BoardClient, timeout: float = 2.0) -> tuple[float, ...]:
    """Measured servo positions from telemetry (advancing a lockstep board a little if needed)."""
    return (await _first_telemetry(client, timeout)).positions


async def stream_trajectory(
    client: BoardClient,
    times_s: Sequence[float] | np.ndarray,
    positions: np.ndarray,
    *,
    mask: int = ALL_SERVOS,
    lookahead_s: float = 0.05,
    lead_s: float = 0.3,
    wall_timeout_s: float = 10.0,
) -> tuple[int, int, list[int]]:
    """Send one frame per sample; returns ``(t0_board_us, t_end_board_us, seqs)``.

    Raises :class:`NackError` as soon as the board refuses one of the frames.
    """
    nacks: list[Nack] = []
    seqs: set[int] = set()

    def on_nack(n: Nack) -> None:
        if n.ack_seq in seqs:
            nacks.append(n)

    client.on_nack.append(on_nack)
    try:
        t0 = client.board_now_estimate() + int(lookahead_s * 1e6)
        lead_us = int(lead_s * 1e6)
        sent: list[int] = []
        apply = [t0 + int(round(float(t) * 1e6)) for t in times_s]
        for k, at in enumerate(apply):
            if nacks:
                raise NackError(nacks[0])
            horizon = at - lead_us
            if client.lockstep:
                if client.board_now_estimate() < horizon:
                    def reached(t: Telemetry, h: int = horizon) -> bool:
                        return t.board_time_us >= h

                    await client.wait_for(reached, wall_timeout_s)
            else:
                ahead = horizon - client.board_now_estimate()
                if ahead > 0:
                    await asyncio.sleep(ahead / 1e6)  # pacing on the synced clock
            seq = client.send_frame(ServoFrame(at, mask, tuple(float(v) for v in positions[k])))
            seqs.add(seq)
            sent.append(seq)
        if nacks:
            raise NackError(nacks[0])
        return t0, apply[-1], sent
    finally:
        client.on_nack.remove(on_nack)


async def move_to(
    client: BoardClient,
    target: Sequence[float],
    *,
    duration_s: float = 1.0,
    rate_hz: float = 100.0,
    tolerance_deg: float = 3.0,
    settle_timeout_s: float = 5.0,
    wall_timeout_s: float = 30.0,
    max_speed: Sequence[float] | None = None,
) -> MoveResult:
    """Min-jerk move of all servos to ``target``; returns once telemetry shows every servo within tolerance.

    Raises :class:`LinkTimeout` when the servos do not get there within ``settle_timeout_s`` of
    board time after the trajectory ends (the message names the worst servo), :class:`NackError`
    if the board refuses frames, :class:`LinkError` on a fault (estop, watchdog).
    """
    start = await _first_telemetry(client, wall_timeout_s)
    if start.faults & (FaultFlags.ESTOP | FaultFlags.WATCHDOG_FAULT):
        raise LinkError(f"board is faulted ({FaultFlags(start.faults & FAULT_BITS)!r}); clear it first (estop_clear)")
    q0 = np.asarray(start.positions[: len(target)], dtype=float)
    times, positions = min_jerk(q0, np.asarray(target, dtype=float), duration_s, rate_hz, max_speed)
    _, t_end, seqs = await stream_trajectory(client, times, positions, wall_timeout_s=wall_timeout_s)
    deadline = t_end + int(settle_timeout_s * 1e6)
    step_us = 50_000
    loop = asyncio.get_running_loop()
    wall_end = loop.time() + wall_timeout_s
    while True:
        t = client.latest_telemetry
        if t is not None and t.board_time_us >= t_end:
            err, idx = max_error_deg(t, target)
            if err <= tolerance_deg:
                return MoveResult(err, idx, len(seqs), float(times[-1]), t.board_time_us)
            if t.faults & (FaultFlags.ESTOP | FaultFlags.WATCHDOG_FAULT):
                raise LinkError(f"board faulted during the move: {FaultFlags(t.faults & FAULT_BITS)!r}")
            if t.board_time_us >= deadline:
                raise LinkTimeout(
                    f"servos not within {tolerance_deg} deg of the target {settle_timeout_s} s after the move: "
                    f"largest error {err:.2f} deg on servo index {idx}"
                )
        remaining = wall_end - loop.time()
        if remaining <= 0:
            raise LinkTimeout(f"move did not finish within {wall_timeout_s} s of wall time")
        seen = t.board_time_us if t is not None else -1
        if client.lockstep:
            await client.advance(max(client.board_now_estimate(), t_end) + step_us)

        def newer(x: Telemetry, after: int = seen) -> bool:
            return x.board_time_us > after

        # wait_for also looks at the latest report, so one that arrived with the ACK is not missed
        await client.wait_for(newer, min(remaining, 5.0))
