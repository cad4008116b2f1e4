"""Host -> board -> host round trips over a real pty (board subprocess, host BoardClient).

Prints p50/p99/max of:
* TIME_SYNC round trip (t4 - t1 on the host clock) and the board's turnaround (t3 - t2);
* frame-send -> applied: a SERVO_FRAME due "now" (apply-at = board time estimate) is sent and
  the host waits for the telemetry that reports its sequence as applied (host wall time),
  which bounds send -> jitter buffer -> tick -> telemetry -> host (telemetry period included).

Run: ``python bench/bench_roundtrip.py [--n 300] [--telemetry-rate 500] [--baud N]``. Numbers
depend on the machine's load; they are printed, never asserted.
"""

from __future__ import annotations

import argparse
import asyncio
import time

import numpy as np

from host.link.board_process import start_board
from host.link import BoardClient, host_now_us
from protocol.messages import ServoFrame
from robots.coco import load_poses


def _pct(name: str, xs: list[float]) -> str:
    a = np.asarray(xs)
    return f"{name:<44} n={len(a):4d}  p50={np.percentile(a, 50):8.0f} us  p99={np.percentile(a, 99):8.0f} us  max={a.max():8.0f} us"


async def _run(port: str, n: int, baud: int) -> None:
    neutral = load_poses()["neutral"]
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
    ap.add_argument("--telemetry-rate", type=int, default=500, help="board telemetry rate (default 500 Hz: one report per tick)")
    ap.add_argument("--baud", type=int, default=0, help="let the board model wire time at this baud (0 = raw pty)")
    a = ap.parse_args()
    args = ["--realtime", "--telemetry-rate", str(a.telemetry_rate)] + (["--baud", str(a.baud)] if a.baud else [])
    board = start_board(args)
    print(f"board on {board.port}: {' '.join(args)}")
    try:
        asyncio.run(_run(board.port, a.n, a.baud or 115200))
    finally:
        board.stop()


if __name__ == "__main__":
    main()
