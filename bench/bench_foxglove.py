"""Live view and recording: joint-state rate a Foxglove client receives during a realtime run, and what
recording run.mcap costs a lockstep run.

    PYTHONPATH=. python bench/bench_foxglove.py [--task 26] [--n 3]

Live: a realtime session with ``--foxglove`` (port 0), a WebSocket client speaking the Foxglove protocol
(``foxglove.sdk.v1``) subscribed to ``/joint_states`` while the task runs; per run: messages (and how many
run.mcap holds over the same span: reports the host never got are missing from both), rate by board
time and by wall time, the longest wall gap between two messages. Recording: wall seconds of the same task
in lockstep with and without run.mcap (n runs each, alternating), and the file's size.

``--log-cost SECONDS`` instead times the recorder itself on the host's event-loop thread: the real
:class:`host.run.mcap_log.RunLog` writing an MCAP file, fed what a realtime run feeds it (a 50 Hz
TELEMETRY + SIM_STATE pair, a 100 Hz full-body SERVO_FRAME sent) for SECONDS of board time; it prints
n, p50, p99 and max of the time per ``on_*`` call (a chunk is compressed inside the call that fills
it: that call is the tail), for the recorder's settings and for ``--chunk-kib``/``--zstd-level``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import struct
import tempfile
import time
from pathlib import Path
from typing import Any

import anyio
import websockets

from host.commands.inputs import positive_seconds, whole_number
from host.run.runner import RunOptions, run_program
from host.run.robot_session import RobotSession, SessionOptions
from robots.registry import DEFAULT_ROBOT, load_robot


async def live_once(program: str, out: Path) -> dict[str, Any]:
    got: list[tuple[float, int]] = []
    async with RobotSession(SessionOptions(out=out, foxglove=0)) as s:
        assert s.recording is not None and s.recording.live is not None
        ws = await websockets.connect(f"ws://127.0.0.1:{s.recording.live.port}", subprotocols=["foxglove.sdk.v1"])

        async def watch() -> None:
            subscribed = False
            async with ws:
                async for msg in ws:
                    if isinstance(msg, str):
                        doc = json.loads(msg)
                        if doc["op"] == "advertise" and not subscribed:
                            for c in doc["channels"]:
                                if c["topic"] == "/joint_states":
                                    subscribed = True
                                    await ws.send(json.dumps({"op": "subscribe",
                                                              "subscriptions": [{"id": 1, "channelId": c["id"]}]}))
                    elif msg[0] == 1:
                        got.append((time.monotonic(), struct.unpack_from("<Q", msg, 5)[0]))

        async with anyio.create_task_group() as tg:
            tg.start_soon(watch)
            await s.run_turn(program)
            tg.cancel_scope.cancel()
    wall = got[-1][0] - got[0][0]
    board = (got[-1][1] - got[0][1]) / 1e9
    gaps = [b[0] - a[0] for a, b in zip(got, got[1:])]
    from host.run.mcap_read import McapRun

    recorded = [m.log_time_ns for m in McapRun(out / "run.mcap").messages(["/joint_states"], decode=False)
                if got[0][1] <= m.log_time_ns <= got[-1][1]]
    return {"messages": len(got), "board_hz": (len(got) - 1) / board, "wall_hz": (len(got) - 1) / wall,
            "max_gap_ms": 1000 * max(gaps), "recorded": len(recorded)}


def log_cost(robot: str, seconds: float, chunk_kib: int | None, zstd_level: int | None, out: Path) -> list[float]:
    """Per-call wall time (s) of RunLog's on_message / on_frame_sent over ``seconds`` of a synthetic run."""
    import numpy as np

    import host.run.mcap_log as mcap_log
    from protocol.messages import FaultFlags, ServoFrame, SimState, Telemetry

    if chunk_kib is not None:
        mcap_log.CHUNK_BYTES = chunk_kib * 1024
    if zstd_level is not None:
        mcap_log.ZSTD_LEVEL = zstd_level
    r = load_robot(robot)
    n = len(r.servos.names)
    rng = np.random.default_rng(0)
    run_log = mcap_log.RunLog.create(out, r)
    took: list[float] = []
    try:
        for k in range(max(1, int(seconds * 100))):
            t_us = k * 10_000
            q = tuple(float(v) for v in rng.normal(0.0, 0.3, n))
            calls: list[tuple[Any, tuple[Any, ...]]] = [
                (run_log.on_frame_sent, (k + 1, ServoFrame(t_us + 60_000, (1 << n) - 1, q), t_us))]
            if k % 2 == 0:
                tel = Telemetry(t_us, q, q, q, (0.0, 0.01, 0.02), FaultFlags(0), 6, k, 0, 0, 0)
                sim = SimState(t_us, (0.01 * k, 0.0, 0.1), (1.0, 0.0, 0.0, 0.0))
                calls += [(run_log.on_message, (tel,)), (run_log.on_message, (sim,))]
            for fn, a in calls:
                t0 = time.perf_counter()
                fn(*a)
                took.append(time.perf_counter() - t0)
    finally:
        run_log.close()
    return took


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default=DEFAULT_ROBOT)
    ap.add_argument("--task", type=int, default=26)
    ap.add_argument("--n", type=int, default=3)
    ap.add_argument("--log-cost", type=positive_seconds, metavar="SECONDS",
                    help="time the recorder's calls instead (board s)")
    ap.add_argument("--chunk-kib", type=whole_number(1, 65536), help="with --log-cost: MCAP chunk size (default: the recorder's)")
    ap.add_argument("--zstd-level", type=whole_number(0, 22),
                    help="with --log-cost: zstd level 0-22 (0: zstd's default; default: the recorder's)")
    args = ap.parse_args()
    if args.log_cost is None and (args.chunk_kib is not None or args.zstd_level is not None):
        ap.error("--chunk-kib and --zstd-level need --log-cost")
    if args.log_cost is not None:
        import host.run.mcap_log as mcap_log

        with tempfile.TemporaryDirectory(prefix="bench_foxglove_") as tmp:
            took = sorted(log_cost(args.robot, args.log_cost, args.chunk_kib, args.zstd_level, Path(tmp) / "run.mcap"))
            size = (Path(tmp) / "run.mcap").stat().st_size
        ms = [1e3 * t for t in took]
        p = lambda q: ms[min(len(ms) - 1, int(q * len(ms)))]  # noqa: E731 (nearest rank)
        print(f"RunLog calls, {args.log_cost:g} board s of {args.robot}, chunk {mcap_log.CHUNK_BYTES // 1024} KiB, "
              f"zstd level {mcap_log.ZSTD_LEVEL}: n={len(ms)} p50={p(0.5):.3f} p99={p(0.99):.3f} max={ms[-1]:.3f} ms; "
              f"calls over 1 ms: {sum(1 for x in ms if x > 1.0)}; run.mcap {size / 1024:.0f} KiB")
        return 0
    program = load_robot(args.robot).tasks[args.task].ground_truth
    with tempfile.TemporaryDirectory(prefix="bench_foxglove_") as tmp:
        live = [anyio.run(live_once, program, Path(tmp) / f"live{i}", backend="asyncio") for i in range(args.n)]
        print(f"live /joint_states, task {args.task} realtime, n={args.n} runs:")
        for r in live:
            print(f"  {r['messages']} messages ({r['recorded']} in run.mcap over the same span), {r['board_hz']:.2f} Hz "
                  f"by board time, {r['wall_hz']:.2f} Hz by wall time, longest wall gap {r['max_gap_ms']:.1f} ms")
        times: dict[bool, list[float]] = {True: [], False: []}
        size = 0
        for i in range(args.n):
            for mcap in (True, False):
                out = Path(tmp) / f"rec{i}{mcap}"
                t0 = time.monotonic()
                anyio.run(run_program, RunOptions(program=program, lockstep=True, out=out, mcap=mcap,
                                                  task_label=f"task {args.task}"), backend="asyncio")
                times[mcap].append(time.monotonic() - t0)
                if mcap:
                    size = (out / "run.mcap").stat().st_size
        print(f"lockstep task {args.task}, n={args.n} each: with run.mcap median {statistics.median(times[True]):.2f} s, "
              f"without {statistics.median(times[False]):.2f} s; run.mcap {size / 1024:.0f} KiB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
