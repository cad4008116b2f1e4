"""Host -> board -> host round trips over a real pty or SLCAN (board subprocess, host BoardClient).

Prints p50/p99/max of:
* TIME_SYNC round trip (t4 - t1 on the host clock) and the board's turnaround (t3 - t2);
* frame-send -> applied: a SERVO_FRAME due "now" (apply-at = board time estimate) is sent and
  the host waits for the telemetry that reports its sequence as applied (host wall time),
  which bounds send -> jitter buffer -> tick -> telemetry -> host (telemetry period included).

Over CAN (``--link can:slcan:pty``) the board is a SLCAN adapter on a pty and the host is python-can's
own ``slcan`` interface: a TIME_SYNC request is one classic frame, its reply three (one on FD); a
SERVO_FRAME is five classic frames (one FD frame); a 12-servo TELEMETRY report is 17 classic frames,
so the board reports at 100 Hz there (500 Hz, one report per tick, on the pty).

Run: ``python bench/bench_roundtrip.py [--n 300] [--telemetry-rate 500] [--baud N] [--link SPEC]``
(``--link pty``, the default, ``can:slcan:pty`` or ``'can:slcan:pty?fd=1'``). Numbers depend on the
machine's load; they are printed, never asserted.
"""

from __future__ import annotations

import argparse
import asyncio
import time

import numpy as np

from host.link.board_process import start_board
from host.link import BoardClient, host_now_us
from protocol.linkkinds import link_kind
from protocol.linkspec import LinkSpec, LinkSpecError, parse_link_spec
from protocol.messages import ServoFrame
from robots.registry import load_robot


def _pct(name: str, xs: list[float]) -> str:
    a = np.asarray(xs)
    return f"{name:<44} n={len(a):4d}  p50={np.percentile(a, 50):8.0f} us  p99={np.percentile(a, 99):8.0f} us  max={a.max():8.0f} us"


async def _run(port: str | LinkSpec, n: int, baud: int) -> None:
    neutral = load_robot().servos.neutral
    async with await BoardClient.connect(port, baud=baud) as c:
        rtt, turn = [], []
        for _ in range(n):
            t1, t2, t3, t4 = await c.sync_once()
            rtt.append(t4 - t1)
            turn.append(t3 - t2)
        est = c.clock_estimate
        lat = []
        for _ in range(n // 3):
            t_send = time.monotonic()
            seq = c.send_frame(ServoFrame(c.board_now_estimate(), 0xFFF, neutral))
            await c.wait_for(lambda t, s=seq: t.last_applied_seq == s, 2.0)
            lat.append((time.monotonic() - t_send) * 1e6)
        print(_pct("TIME_SYNC round trip (host t4 - t1)", rtt))
        print(_pct("board turnaround (t3 - t2)", turn))
        print(_pct("frame sent -> telemetry shows it applied", lat))
        if est is not None:
            print(f"clock estimate: offset {est.offset_us:.0f} us, drift {est.drift_ppm:.2f} ppm, "
                  f"uncertainty +-{est.uncertainty_us:.0f} us from {est.samples_used} samples")
        print(f"late {c.latest_telemetry.late_count if c.latest_telemetry else '?'}, nacks {c.stats.frame_nacks}, "
              f"decode errors {c.stats.decode_errors}, host clock now {host_now_us()} us")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=300)
    ap.add_argument("--telemetry-rate", type=int, default=None,
                    help="board telemetry rate (default 500 Hz on the pty: one report per tick; 100 Hz on CAN)")
    ap.add_argument("--baud", type=int, default=0, help="let the board model wire time at this baud (0 = raw pty)")
    ap.add_argument("--link", default="pty", metavar="SPEC", help="pty (default), can:slcan:pty or 'can:slcan:pty?fd=1'")
    a = ap.parse_args()
    try:
        spec = parse_link_spec(a.link)
    except LinkSpecError as e:
        ap.error(f"--link: {e}")
    if not spec.implies_emulated_board:
        ap.error(f"--link {a.link}: the benchmark starts its own board; use pty or can:slcan:pty")
    if a.telemetry_rate is None:
        # a 12-servo report is 17 classic CAN frames: 500 Hz would need ~115 % of a 1 Mbit/s bus, and the
        # lowest-priority ISO-TP flow control would starve behind it (the handshake fails); 100 Hz is ~23 %
        a.telemetry_rate = 100 if link_kind(spec).wire == "can" else 500
    args = ["--realtime", "--telemetry-rate", str(a.telemetry_rate)] + (["--baud", str(a.baud)] if a.baud else [])
    board = start_board(args, link=spec)
    print(f"board on {board.port} (link {spec}): {' '.join(args)}")
    try:
        asyncio.run(_run(board.spec, a.n, a.baud or 115200))
    finally:
        board.stop()


if __name__ == "__main__":
    main()
