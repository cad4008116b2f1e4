"""What recording run.mcap costs the host's event loop: the RunLog's work done on the loop (as it was) and
handed to the recording's writer thread (as it is), for any robot.

    PYTHONPATH=. python bench/bench_recording.py [--robot coco] [--mesh-arm] [--seconds 10]

A synthetic realtime feed on a real asyncio loop, paced by the wall clock: a 50 Hz TELEMETRY + SIM_STATE
pair and a 100 Hz full-body SERVO_FRAME sent, into a real :class:`host.run.mcap_log.RunLog` writing a
real MCAP. Three modes, each for SECONDS: ``none`` (no recording: the loop's own lag), ``loop`` (each
RunLog call inline in the callback, as the recording did before its writer thread), ``thread`` (each
call handed to :class:`host.run.log_writer.LogWriter`). Printed per mode: n reports and the loop's cost
per report (p50, p99, max ms), and the lag of a 1 ms ticker task on the same loop (p50, p99, max ms):
what a frame or heartbeat due then waited. ``--mesh-arm`` writes tests/support's 6-servo arm with 13
STL meshes (~100 000 triangles) and uses it. Also printed: the scene's build time and STL bytes.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from host.commands.inputs import positive_seconds  # noqa: E402
from host.run.log_writer import LogWriter  # noqa: E402
from host.run.mcap_log import RunLog  # noqa: E402
from host.run.scene3d import RobotScene  # noqa: E402
from protocol.messages import FaultFlags, ServoFrame, SimState, Telemetry  # noqa: E402
from robots.description import Robot  # noqa: E402
from robots.registry import load_robot  # noqa: E402


def _pct(xs: list[float]) -> str:
    a = np.sort(np.asarray(xs)) * 1e3
    return f"p50 {np.percentile(a, 50):.3f} p99 {np.percentile(a, 99):.3f} max {a[-1]:.1f} ms"


async def _run(robot: Robot, mode: str, seconds: float, out: Path) -> tuple[list[float], list[float], int]:
    """(loop cost per report s, ticker lag s, dropped) of one mode."""
    n = robot.servo_count
    run_log = RunLog.create(out, robot) if mode != "none" else None
    writer = LogWriter().start() if mode == "thread" else None
    if writer is not None and run_log is not None:
        writer.submit(run_log.prepare)
    elif run_log is not None:
        run_log.prepare()

    def do(fn: Any, *args: Any) -> None:
        if writer is not None:
            writer.submit(fn, *args)
        elif run_log is not None:
            fn(*args)

    lags: list[float] = []
    costs: list[float] = []
    stop = asyncio.Event()

    async def ticker() -> None:
        while not stop.is_set():
            t = time.perf_counter()
            await asyncio.sleep(0.001)
            lags.append(max(0.0, time.perf_counter() - t - 0.001))

    async def feed() -> None:
        rng = np.random.default_rng(0)
        t0 = time.perf_counter()
        for k in range(int(seconds * 100)):
            await asyncio.sleep(max(0.0, t0 + k * 0.01 - time.perf_counter()))
            t_us = k * 10_000
            q = tuple(float(v) for v in rng.normal(0.0, 0.3, n))
            a = time.perf_counter()
            if run_log is not None:
                do(run_log.on_frame_sent, k + 1, ServoFrame(t_us + 60_000, (1 << n) - 1, q), t_us)
                if k % 2 == 0:
                    do(run_log.on_message, Telemetry(t_us, q, q, q, (0.0, 0.01, 0.02), FaultFlags(0), 6, k, 0, 0, 0))
                    do(run_log.on_message, SimState(t_us, (0.01 * k, 0.0, 0.1), (1.0, 0.0, 0.0, 0.0)))
            if k % 2 == 0:
                costs.append(time.perf_counter() - a)
        stop.set()

    await asyncio.gather(ticker(), feed())
    dropped = 0
    if writer is not None:
        writer.submit(run_log.close)  # type: ignore[union-attr]
        writer.close(60)
        dropped = writer.dropped
    elif run_log is not None:
        run_log.close()
    return costs, lags, dropped


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default="coco")
    ap.add_argument("--robots-dir", default=None)
    ap.add_argument("--mesh-arm", action="store_true", help="tests/support's arm with 13 STL meshes")
    ap.add_argument("--seconds", type=positive_seconds, default=10.0, help="wall seconds per mode")
    ap.add_argument("--modes", default="none,loop,thread", help="comma-separated: none, loop, thread")
    args = ap.parse_args()
    modes = args.modes.split(",")
    if not modes or any(m not in ("none", "loop", "thread") for m in modes):
        ap.error(f"--modes: expected none, loop and/or thread, got {args.modes!r}")
    with tempfile.TemporaryDirectory(prefix="bench_recording_") as tmp:
        if args.mesh_arm:
            from tests.support.mesh_robot import write_mesh_arm

            robot = load_robot("mesh_arm", write_mesh_arm(Path(tmp) / "arm"))
        else:
            robot = load_robot(args.robot, args.robots_dir)
        t = time.perf_counter()
        scene = RobotScene(robot)
        built = time.perf_counter() - t
        print(f"{robot.name}: RobotScene built in {built * 1e3:.0f} ms, {scene.mesh_bytes / 1e6:.2f} MB of STL "
              f"({len(scene.boxed_meshes)} mesh(es) boxed); {args.seconds:g} s per mode, wall-clock paced")
        for mode in modes:
            costs, lags, dropped = asyncio.run(_run(robot, mode, args.seconds, Path(tmp) / f"{mode}.mcap"))
            print(f"  {mode:<6} loop cost per report n={len(costs)} {_pct(costs)}; 1 ms ticker lag n={len(lags)} "
                  f"{_pct(lags)}" + (f"; dropped {dropped}" if mode == "thread" else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
