"""Board benchmarks (prints numbers, asserts nothing).

1. Lockstep speed: ticks/s of the board core (500 Hz, dt 2 ms, telemetry 50 Hz) and the
   real-time factor (simulated seconds per wall second).
2. Realtime pacing: a real board process on a pty at 500 Hz for ``--seconds`` (default 10)
   while a host feeds heartbeats and reads telemetry; tick lateness p50/p99/max from the
   board's own statistics (printed on SIGTERM).
3. TIME_SYNC round trip over the pty (host write -> board reply -> host read), realtime board.

``--robot NAME`` (default: the default robot) picks whose board runs; the lockstep stream moves
every servo of that robot (a sine of 0.2 rad around its neutral pose, clipped to the ranges).

Run: ``.venv/bin/python bench/bench_board.py [--seconds 10] [--robot NAME]``
"""

from __future__ import annotations

import argparse
import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import serial

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from firmware_sim.board import Board  # noqa: E402
from firmware_sim.config import BoardConfig  # noqa: E402
from protocol.codec import SCHEMA_HASH  # noqa: E402
from protocol.framing import Frame, FrameDecoder, encode_frame  # noqa: E402
from protocol.messages import PROTOCOL_VERSION, Heartbeat, Hello, Telemetry, TimeSyncReply, TimeSyncRequest  # noqa: E402


def bench_lockstep(robot: str, sim_seconds: float = 30.0) -> None:
    b = Board(BoardConfig(lockstep=True, robot=robot))
    b.handle(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 0), 0)
    from protocol.messages import ServoFrame

    # a moving stream (every servo) at 50 Hz, fed 1 s ahead, so buffer and interpolation are exercised
    neutral = np.array(b.table.neutral)
    lo, hi = np.array(b.table.mins), np.array(b.table.maxs)
    mask = b.table.all_mask
    n_frames = int(sim_seconds * 50)
    t0, c0 = time.perf_counter(), time.process_time()
    for k in range(1, n_frames + 1):
        q = np.clip(neutral + 0.2 * np.sin(2 * np.pi * k / 50), lo, hi)
        b.handle(ServoFrame(k * 20_000, mask, tuple(q)), k)
        if k % 50 == 0 or k == n_frames:
            while b.can_tick():
                b.tick()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    n = b.ticks
    print(f"lockstep ({robot}, {b.n} servos, scene {b.scene}): {n} ticks in {wall:.2f} s = {n / wall:,.0f} ticks/s, real-time factor {n * 0.002 / wall:.1f}x"
          f" (CPU time {cpu:.2f} s = {n / cpu:,.0f} ticks/s, {n * 0.002 / cpu:.1f}x: what a busy machine hides)")


def _start_board(*extra: str) -> tuple[subprocess.Popen[str], str]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "firmware_sim", "--link", "pty", *extra],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env=dict(os.environ, PYTHONUNBUFFERED="1"),
    )
    assert proc.stdout is not None
    line = proc.stdout.readline().strip()
    return proc, line.removeprefix("board: listening on ")


def bench_realtime(robot: str, seconds: float) -> None:
    proc, port = _start_board("--realtime", "--robot", robot)
    tel = 0
    try:
        with serial.Serial(port, 115200, timeout=0) as ser:
            dec = FrameDecoder()
            ser.write(encode_frame(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 0), 0))
            end = time.monotonic() + seconds
            seq = 1
            next_hb = 0.0
            while time.monotonic() < end:
                if time.monotonic() >= next_hb:
                    ser.write(encode_frame(Heartbeat(0), seq))
                    seq += 1
                    next_hb = time.monotonic() + 0.05
                select.select([ser.fileno()], [], [], 0.05)
                tel += sum(1 for f in dec.feed(ser.read(65536)) if isinstance(f, Frame) and isinstance(f.msg, Telemetry))
            # round trip: TIME_SYNC request -> reply
            rtts = []
            for _ in range(200):
                t1 = time.perf_counter()
                ser.write(encode_frame(TimeSyncRequest(int(t1 * 1e6)), seq))
                seq += 1
                got = False
                while not got:
                    select.select([ser.fileno()], [], [], 0.5)
                    got = any(isinstance(f, Frame) and isinstance(f.msg, TimeSyncReply) for f in dec.feed(ser.read(65536)))
                rtts.append(time.perf_counter() - t1)
    finally:
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=10)
    summary = [line for line in err.splitlines() if "lateness" in line]
    print(f"realtime 500 Hz ({robot}) for {seconds:.0f} s: {summary[-1] if summary else err}")
    print(f"  telemetry received: {tel} ({tel / seconds:.1f}/s)")
    r = np.array(rtts) * 1e3
    print(f"  TIME_SYNC round trip over pty: p50 {np.percentile(r, 50):.2f} ms, p99 {np.percentile(r, 99):.2f} ms, max {r.max():.2f} ms")


def main() -> None:
    from robots.registry import DEFAULT_ROBOT

    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--robot", default=DEFAULT_ROBOT, help=f"whose board runs (default {DEFAULT_ROBOT})")
    args = ap.parse_args()
    bench_lockstep(args.robot)
    bench_realtime(args.robot, args.seconds)


if __name__ == "__main__":
    main()
