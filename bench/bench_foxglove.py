"""Live view and recording: joint-state rate a Foxglove client receives during a realtime run, and what
recording run.mcap costs a lockstep run.

    PYTHONPATH=. python bench/bench_foxglove.py [--task 26] [--n 3]

Live: a realtime session with ``--foxglove`` (port 0), a WebSocket client speaking the Foxglove protocol
(``foxglove.sdk.v1``) subscribed to ``/joint_states`` while the task runs; per run: messages (and how many
run.mcap holds over the same span: reports the host never got are missing from both), rate by board
time and by wall time, the longest wall gap between two messages. Recording: wall seconds of the same task
in lockstep with and without run.mcap (n runs each, alternating), and the file's size.
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

from host.run.runner import RunOptions, run_program
from host.run.session import RobotSession, SessionOptions
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


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default=DEFAULT_ROBOT)
    ap.add_argument("--task", type=int, default=26)
    ap.add_argument("--n", type=int, default=3)
    args = ap.parse_args()
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
