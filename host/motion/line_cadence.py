"""The link's cadence on a slow serial line: the frame grid, the board's watchdog and its report rate.

A session plans its traffic from the line's baud rate (8N1, :data:`protocol.wiremodel.BITS_PER_BYTE`)
before it starts (:func:`line_cadence`), and settles the board's side in the handshake (HELLO/CAPS, then
the CONFIGs of :meth:`LineCadence.config`, then TIME_SYNC: :class:`host.link.supervisor.Supervisor`).

The rule for the watchdog (the link-loss timeout): it must cover the host's own cadence. The host sends a
SERVO_FRAME every grid period ``P`` (:func:`host.motion.streamer.grid_period_us`: 10 ms on a fast line;
for a 12-servo robot at 2 400 baud, where a full-body frame is 162 ms of wire, it was 330 ms). The board's
default watchdog (200 ms) is shorter than that grid below ~11 000 baud (:func:`host.motion.streamer.slow_line`):
every gap between two frames tripped it (HOLD, the jitter buffer emptied, the motion lost), and
heartbeats sent into the gaps needed more than the line. So on a slow line the host raises the watchdog
to ``3 * P`` with CONFIG
WATCHDOG_MS, or to one grid period more than the report period when that is longer (a lockstep host
whose board went quiet ADVANCEs it one report period with no frame in it: that must not trip it):
CANopen node guarding's rule (life time = guard time x life time factor, the factor
typically 3): one frame lost to line noise, and a period of jitter, do not trip it; a line that went
silent does within three periods. Any valid message still feeds it (both boards), and the host's
heartbeat then fills only a gap of half the watchdog (``1.5 * P``: never while the grid streams).
With no heartbeat in its gaps, the slow grid may fill more of the line
(:data:`host.motion.streamer.SLOW_GRID_LINE_SHARE`, 210 ms at 2 400 baud) and its frames carry only the
servos that move (``FrameStreamer.sparse``): the bandwidth goes where the motion is, and a stride's 0.7-s
gait cycle keeps its shape (Task 26's strides move CoCo 7.3 cm at 2 400 baud, 8.2 at full rate, 1.8
with the old 330 ms grid). Sparse frames alone would not have done: a stride moves 8 of CoCo's 12
servos (31 of 39 bytes); nor more heartbeats, into a line already full.

The board's reports: at 50 Hz CoCo's TELEMETRY + SIM_STATE need 81 500 bit/s. On a line that raises the
watchdog the host also lowers the report rate (CONFIG TELEMETRY_RATE_HZ) to what fills at most
:data:`TELEMETRY_LINE_SHARE` of the line (at least 1 Hz): a realtime board dropped the rest anyway, and
a lockstep board, which waits for its line rather than drop a report, ran at 0.03x real time.

A line too slow for the robot at all is refused before anything starts (:class:`LineTooSlow`): when the
board's slowest reports (1 Hz) and the TIME_SYNC replies (2 Hz) need more than the whole line (below
~2 300 baud for CoCo: at 1 200 baud a report pair alone is 1.4 s of wire, and a run would stall mid-way
waiting for confirmations that cannot arrive).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from host.motion.streamer import BOARD_WATCHDOG_US, WATCHDOG_GRID_PERIODS, grid_period_us, slow_line
from protocol.codec import WireSchema, schema_for
from protocol.framing import encode_frame
from protocol.messages import ConfigKey, FaultFlags, SimState, Telemetry, TimeSyncReply
from protocol.wiremodel import BITS_PER_BYTE

__all__ = ["BOARD_TELEMETRY_HZ", "BOARD_WATCHDOG_MS", "SYNC_REPLIES_HZ", "TELEMETRY_LINE_SHARE",
           "WATCHDOG_GRID_PERIODS", "LineCadence", "LineTooSlow", "line_cadence", "report_pair_bytes"]

#: the board's defaults (both boards, ``firmware_sim.config.BoardConfig``; CAPS reports the report rate)
BOARD_WATCHDOG_MS = BOARD_WATCHDOG_US // 1000
BOARD_TELEMETRY_HZ = 50
CONTROL_RATE_HZ = 500
#: the share of the board -> host line the reports may fill once the host lowers their rate
TELEMETRY_LINE_SHARE = 0.5
#: TIME_SYNC replies per second on a realtime link (the supervisor's ``sync_interval_s`` of 0.5 s)
SYNC_REPLIES_HZ = 2
#: the UART rates a refusal names the lowest working one of
STANDARD_BAUDS = (300, 600, 1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200)


class LineTooSlow(ValueError):
    """The line cannot carry the robot at all (one line: the rate, what it would need, the lowest rate that works)."""


def report_pair_bytes(n_servos: int, schema: WireSchema | None = None) -> int:
    """Wire bytes of one TELEMETRY and one SIM_STATE for ``n_servos`` (framing and COBS included)."""
    schema = schema or schema_for(max(1, n_servos))
    z = (0.0,) * n_servos
    tel = Telemetry(0, z, z, z, (0.0, 0.0, 0.0), FaultFlags.NONE, 0, 0, 0, 0, 0)
    sim = SimState(0, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0))
    return len(encode_frame(tel, 0, schema)) + len(encode_frame(sim, 0, schema))


@dataclass(frozen=True)
class LineCadence:
    """A session's cadence on its line: ``period_us`` the frame grid (µs), ``watchdog_ms`` the board
    watchdog to ask for (None: the board's default covers the grid), ``telemetry_hz`` the report rate to
    ask for (None: the board's default)."""

    period_us: int
    watchdog_ms: int | None = None
    telemetry_hz: int | None = None

    def config(self) -> tuple[tuple[ConfigKey, int], ...]:
        """The CONFIGs the handshake sends (key, value), watchdog first; empty on a fast line."""
        out: list[tuple[ConfigKey, int]] = []
        if self.watchdog_ms is not None:
            out.append((ConfigKey.WATCHDOG_MS, self.watchdog_ms))
        if self.telemetry_hz is not None:
            out.append((ConfigKey.TELEMETRY_RATE_HZ, self.telemetry_hz))
        return tuple(out)

    def heartbeat_s(self) -> float | None:
        """The heartbeat interval (s) for a raised watchdog: half of it; None when the watchdog is the default."""
        return None if self.watchdog_ms is None else self.watchdog_ms / 2000


def line_cadence(n_servos: int, baud: int | None, schema: WireSchema | None = None) -> LineCadence:
    """The cadence for a robot of ``n_servos`` over a line of ``baud`` bit/s (None: not modelled, a fast
    line). Raises :class:`LineTooSlow` when the board's slowest reports (1 Hz) and the TIME_SYNC replies
    (:data:`SYNC_REPLIES_HZ`) need more than the whole line."""
    period = grid_period_us(n_servos, baud, schema)
    if not baud:
        return LineCadence(period)
    schema = schema or schema_for(max(1, n_servos))
    pair_bits = report_pair_bytes(n_servos, schema) * BITS_PER_BYTE
    sync_bits = SYNC_REPLIES_HZ * len(encode_frame(TimeSyncReply(0, 0, 0), 0, schema)) * BITS_PER_BYTE
    if pair_bits + sync_bits > baud:
        raise LineTooSlow(
            f"--baud {baud} is too slow for a {n_servos}-servo robot: the board's reports at their slowest (1 Hz) "
            f"and the clock sync need ~{pair_bits + sync_bits:,} bit/s, more than the line; use --baud "
            f"{min(r for r in STANDARD_BAUDS if r >= pair_bits + sync_bits)} or more")
    if not slow_line(n_servos, baud, schema):
        return LineCadence(period)
    hz = max(1, min(BOARD_TELEMETRY_HZ, int(TELEMETRY_LINE_SHARE * baud // pair_bits)))
    # a lockstep host's nudge ADVANCEs a silent board one report period (+ a tick) with no frame in it
    nudge_us = 1_000_000 // hz + 1_000_000 // CONTROL_RATE_HZ
    watchdog_ms = math.ceil(max(WATCHDOG_GRID_PERIODS * period, period + nudge_us) / 10_000) * 10
    return LineCadence(period, watchdog_ms, hz if hz < BOARD_TELEMETRY_HZ else None)
