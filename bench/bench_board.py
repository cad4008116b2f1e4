"""Board benchmarks (prints numbers, asserts nothing).

1. Lockstep rates, three on the same moving stream (50 Hz frames moving every servo, 500 Hz ticks,
   telemetry 50 Hz), interleaved round by round (bare, core, pty, bare, ...; ``--rounds``, default 3,
   ``--sim-seconds`` of board time each, default 10) with their ratios per round and the medians:
   - *bare mj_step*: the robot's MjModel stepped alone in C (``mujoco.rollout``) from the board's start
     state with the ``ctrl`` the board wrote at each tick (recorded untimed beforehand; the final state is
     checked to be the board's): the physics alone, the floor;
   - *board core*: ``Board.handle`` + ``Board.run`` as the lockstep server calls them, no I/O (the host's
     frames are made before the clock starts), for the kernel ``$GHOSTSHELL_BOARD_KERNEL`` picks
     (``native``, the default, or ``python``; see firmware_sim.native);
   - *pty path*: a ``--lockstep`` board process on a pty fed 1 s of frames ahead by this process (host
     encode -> pty -> board -> TELEMETRY + SIM_STATE -> host decode); also the CPU per 20 ms of board
     time of the board process (per thread: the main one and the native kernel's) and of the host side;
     and the same with the board's link work during each run of ticks instead of after it
     (``$GHOSTSHELL_LOCKSTEP_OVERLAP=1``, firmware_sim.server; off by default), the A/B of that overlap.
   Then both kernels A/B, interleaved in one process (CPU time per tick, min and median of 7 rounds: on
   a shared machine the minimum is the least disturbed).
2. Realtime pacing: a real board process on a pty at 500 Hz for ``--seconds`` (default 10)
   while a host feeds heartbeats and reads telemetry; tick lateness p50/p99/max from the
   board's own statistics (printed on SIGTERM).
3. TIME_SYNC round trip over the pty (host write -> board reply -> host read), realtime board.

``--robot NAME`` (default: the default robot) picks whose board runs; the moving stream moves every
servo of that robot (a 1 Hz sine of 0.2 rad around its neutral pose, clipped to the servo table's ranges).

Run: ``.venv/bin/python bench/bench_board.py [--seconds 10] [--lockstep-only | --realtime-only] [--robot NAME]
[--rounds 3] [--sim-seconds 10]`` (``GHOSTSHELL_BOARD_KERNEL=python`` for the reference path; ``--profile FILE``
writes the first pty board process's cProfile stats, timed by the main thread's CPU time; ``--host-profile
FILE`` one more pty run's host side, timed by CPU time).
"""

from __future__ import annotations

import argparse
import cProfile
import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import mujoco
import mujoco.rollout
import numpy as np
import serial

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from firmware_sim.board import Board  # noqa: E402
from firmware_sim.config import BoardConfig  # noqa: E402
from host.commands.inputs import positive_seconds  # noqa: E402
from protocol.codec import SCHEMA_HASH, schema_for  # noqa: E402
from protocol.framing import Frame, FrameDecoder, encode_frame  # noqa: E402
from protocol.messages import (PROTOCOL_VERSION, Heartbeat, Hello, ServoFrame, Telemetry, TimeSyncReply,  # noqa: E402
                               TimeSyncRequest)


def bench_lockstep(robot: str, sim_seconds: float = 10.0, rounds: int = 3, profile: str | None = None) -> None:
    """The three lockstep rates on the same moving stream, interleaved round by round (bare, core, pty,
    bare, ...; on a shared machine a load change hits all three alike), and the ratios per round and
    their median: the part of bare MuJoCo the board core and the whole pty path keep."""
    rows: list[tuple[float, float, float, float]] = []
    for r in range(rounds):
        bare = lockstep_bare(robot, sim_seconds, verbose=r == 0)
        core = lockstep_core(robot, sim_seconds, verbose=r == 0)
        pty = lockstep_pty(robot, sim_seconds, profile=profile if r == 0 else None, verbose=r == 0)
        over = lockstep_pty(robot, sim_seconds, verbose=False, overlap=True)
        rows.append((bare, core, pty, over))
        print(f"  round {r + 1}: bare mj_step {bare:,.0f} ticks/s ({bare * 0.002:.1f}x), core {core:,.0f} "
              f"({core * 0.002:.1f}x), pty {pty:,.0f} ({pty * 0.002:.1f}x), pty with overlap {over:,.0f} "
              f"({over * 0.002:.1f}x); core/bare {core / bare:.3f}, pty/bare {pty / bare:.3f}, "
              f"pty/core {pty / core:.3f}, with overlap pty/bare {over / bare:.3f}")
    med = [sorted(col)[len(col) // 2] for col in zip(*rows)]
    ratios = [sorted(x[i] / x[j] for x in rows)[len(rows) // 2] for i, j in ((1, 0), (2, 0), (2, 1), (3, 0))]
    print(f"lockstep rates ({robot}, {sim_seconds:g} s simulated per run, median of n = {rounds} interleaved rounds): "
          f"bare mj_step {med[0]:,.0f} ticks/s ({med[0] * 0.002:.1f}x real time), board core {med[1]:,.0f} "
          f"({med[1] * 0.002:.1f}x), pty path {med[2]:,.0f} ({med[2] * 0.002:.1f}x); "
          f"core/bare {ratios[0]:.3f}, pty/bare {ratios[1]:.3f}, pty/core {ratios[2]:.3f}; "
          f"pty with overlap ($GHOSTSHELL_LOCKSTEP_OVERLAP=1) {med[3]:,.0f} ({med[3] * 0.002:.1f}x), "
          f"pty/bare {ratios[3]:.3f}")


def _stream(b: Board, sim_seconds: float) -> list[ServoFrame]:
    """The moving stream for ``sim_seconds``: one frame every 20 ms (50 Hz), every servo."""
    return [ServoFrame(k * 20_000, b.table.all_mask, _stream_targets(b, k)) for k in range(1, int(sim_seconds * 50) + 1)]


def lockstep_bare(robot: str, sim_seconds: float = 10.0, verbose: bool = True) -> float:
    """Ticks/s of bare MuJoCo on the stream: the board's model stepped alone in C (``mujoco.rollout``, no
    Python per step), from the board's start state, with the very ``ctrl`` the board wrote at each tick
    (recorded beforehand, untimed, by a board fed the stream: targets interpolated, through the servo
    model). So the physics is the board's to the bit (checked: the final ``qpos`` must match) and only
    the board's own work is missing: the floor."""
    b = Board(BoardConfig(lockstep=True, robot=robot))
    m = b.model
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state0 = np.empty(mujoco.mj_stateSize(m, spec))
    mujoco.mj_getState(m, b.data, state0, spec)
    warm0 = b.data.qacc_warmstart.copy()
    b.handle(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 0), 0)
    ctrl: list[np.ndarray] = []
    for k, frame in enumerate(_stream(b, sim_seconds), 1):
        b.handle(frame, k)
        while b.can_tick():
            b.tick()
            ctrl.append(b.data.ctrl.copy())
    control = np.repeat(np.array(ctrl), b.cfg.substeps, axis=0)[None]  # (1, ticks * substeps, nu)
    d = mujoco.MjData(m)
    t0, c0 = time.perf_counter(), time.process_time()
    states, _ = mujoco.rollout.rollout(m, d, state0[None], control, initial_warmstart=warm0[None])
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    ticks = len(ctrl)
    qpos = states[0, -1, 1:1 + m.nq]  # FULLPHYSICS: time, qpos, ...
    if not np.array_equal(qpos, b.data.qpos):
        print(f"bare mj_step ({robot}): the rollout's final qpos differs from the board's by up to "
              f"{np.abs(qpos - b.data.qpos).max():.3g}: not the board's physics")
    if verbose:
        print(f"bare mj_step ({robot}), n = 1 run: {ticks} ticks in {wall:.2f} s = {ticks / wall:,.0f} ticks/s, "
              f"real-time factor {ticks * 0.002 / wall:.1f}x (CPU time {cpu:.2f} s = {ticks / cpu:,.0f} ticks/s, "
              f"{ticks * 0.002 / cpu:.1f}x)")
    return ticks / wall


def lockstep_core(robot: str, sim_seconds: float = 10.0, verbose: bool = True) -> float:
    """Ticks/s of the board core (handle + :meth:`Board.run`, as the lockstep server calls them) on the stream."""
    b = Board(BoardConfig(lockstep=True, robot=robot))
    b.handle(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 0), 0)
    # a moving stream (every servo) at 50 Hz, fed 1 s ahead, so buffer and interpolation are exercised
    frames = _stream(b, sim_seconds)
    n_frames = len(frames)
    t0, c0 = time.perf_counter(), time.process_time()
    for k, frame in enumerate(frames, 1):
        b.handle(frame, k)
        if k % 50 == 0 or k == n_frames:
            while b.can_tick():
                b.run(256)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    n = b.ticks
    if verbose:
        kernel = "native (C)" if b.native is not None else "python"
        print(f"lockstep core ({robot}, {b.n} servos, scene {b.scene}), {kernel} kernel, n = 1 run: {n} ticks in {wall:.2f} s = {n / wall:,.0f} ticks/s, real-time factor {n * 0.002 / wall:.1f}x"
              f" (CPU time {cpu:.2f} s = {n / cpu:,.0f} ticks/s, {n * 0.002 / cpu:.1f}x: what a busy machine hides)")
    return n / wall


def bench_kernels_ab(robot: str, rounds: int = 7, frames: int = 500) -> None:
    per_tick: dict[str, list[float]] = {"python": [], "native": []}
    for _ in range(rounds):
        for kernel, got in per_tick.items():
            b = Board(BoardConfig(lockstep=True, kernel=kernel, robot=robot))
            if kernel == "native" and b.native is None:
                print("kernels A/B: the native kernel is unavailable here (see the note above)")
                return
            b.handle(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 0), 0)
            stream = [ServoFrame(k * 20_000, b.table.all_mask, _stream_targets(b, k)) for k in range(1, frames + 1)]
            c0 = time.process_time()
            for k, frame in enumerate(stream, 1):
                b.handle(frame, k)
                if k % 50 == 0:
                    while b.can_tick():
                        b.run(256)
            got.append((time.process_time() - c0) / b.ticks)
    for kernel, got in per_tick.items():
        got.sort()
        lo, mid = got[0], got[len(got) // 2]
        print(f"kernels A/B, {kernel}: CPU per tick min {lo * 1e6:.1f} us ({0.002 / lo:.0f}x real time), "
              f"median {mid * 1e6:.1f} us ({0.002 / mid:.0f}x), n = {rounds} x {frames * 10} ticks")


def _stream_targets(b: Board, k: int) -> tuple[float, ...]:
    """Frame ``k`` of the benchmark's moving stream for ``b``'s robot: every servo at 1 Hz, 0.2 rad
    around its neutral pose, clipped to the servo table's ranges (rad)."""
    q = np.array(b.table.neutral) + 0.2 * np.sin(2 * np.pi * k / 50)
    return tuple(np.clip(q, b.table.mins, b.table.maxs).tolist())  # floats, as the codec decodes them


def lockstep_pty(robot: str, sim_seconds: float = 10.0, profile: str | None = None, verbose: bool = True,
                 host_profile: str | None = None, overlap: bool = False) -> float:
    """Ticks/s of the whole lockstep path: a ``--lockstep`` board process on a pty fed 1 s of frames
    ahead by this process (host encode -> pty -> board -> TELEMETRY and SIM_STATE -> host decode; the
    frames' targets are made before the clock starts, their encoding is timed). The host writes each
    batch of frames in one ``write`` and reads in 64 KiB chunks; it decodes every report."""
    proc, port = _start_board("--lockstep", "--robot", robot,
                              head=("-c", _CPU_PROFILE, profile) if profile else ("-m", "firmware_sim"),
                              env={"GHOSTSHELL_LOCKSTEP_OVERLAP": "1" if overlap else "0"})
    ref = Board(BoardConfig(lockstep=True, kernel="python", robot=robot))
    schema = schema_for(ref.n)
    stream = _stream(ref, sim_seconds)
    end_us, board_us, tel, k = len(stream) * 20_000, 0, 0, 0
    prof = cProfile.Profile(time.process_time) if host_profile else None
    try:
        with serial.Serial(port, 115200, timeout=0) as ser:
            fd = ser.fileno()
            dec = FrameDecoder(schema=schema)
            t0, cpu0, hcpu0, threads0 = time.perf_counter(), _cpu_s(proc.pid), time.process_time(), _thread_cpu_s(proc.pid)
            if prof is not None:
                prof.enable()
            ser.write(encode_frame(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 0), 0))
            while board_us < end_us - 20_000:
                batch = []
                while k < len(stream) and (k + 1) * 20_000 < board_us + 1_000_000:  # keep 1 s of frames ahead
                    k += 1
                    batch.append(encode_frame(stream[k - 1], k, schema))
                if batch:
                    ser.write(b"".join(batch))
                select.select([fd], [], [], 1.0)
                try:
                    data = os.read(fd, 65536)
                except BlockingIOError:
                    continue
                for f in dec.feed(data):
                    if isinstance(f, Frame) and isinstance(f.msg, Telemetry):
                        tel += 1
                        board_us = max(board_us, f.msg.board_time_us)
            if prof is not None:
                prof.disable()
            wall, cpu, hcpu = time.perf_counter() - t0, _cpu_s(proc.pid) - cpu0, time.process_time() - hcpu0
            threads = {tid: c - threads0.get(tid, 0.0) for tid, c in _thread_cpu_s(proc.pid).items()}
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=60)
    if prof is not None and host_profile:
        prof.dump_stats(host_profile)
    ticks = board_us // 2000
    if verbose:
        print(f"lockstep over pty ({robot}), n = 1 run: {board_us / 1e6:.1f} s simulated in {wall:.2f} s wall = {board_us / 1e6 / wall:.1f}x"
              f" real time ({tel} TELEMETRY read; board process CPU time {cpu:.2f} s = {board_us / 1e6 / cpu:.1f}x;"
              f" CPU per 20 ms of board time: board process {cpu / tel * 1e6:.0f} us, "
              f"host {hcpu / tel * 1e6:.0f} us; of it per board thread, main first: "
              f"{', '.join(f'{c / tel * 1e6:.0f} us' for c in threads.values())})"
              f"{'; board profile in ' + profile if profile else ''}{'; host profile in ' + host_profile if host_profile else ''}")
    return ticks / wall


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of process ``pid`` so far (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _thread_cpu_s(pid: int) -> dict[int, float]:
    """User + system CPU seconds of each thread (id) of process ``pid`` so far, the main thread first (Linux /proc)."""
    out = {}
    for task in sorted(Path(f"/proc/{pid}/task").iterdir(), key=lambda p: int(p.name)):
        try:
            fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        out[int(task.name)] = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    return out


# the board CLI under cProfile timed by CPU time (on a busy machine wall time is mostly waiting):
# python -c _CPU_PROFILE OUT ARGS...
_CPU_PROFILE = """
import cProfile, sys, time
from firmware_sim.cli import main
prof = cProfile.Profile(time.thread_time)
try:
    prof.runcall(main, sys.argv[2:])
finally:
    prof.dump_stats(sys.argv[1])
"""


def _start_board(*extra: str, head: tuple[str, ...] = ("-m", "firmware_sim"),
                 env: dict[str, str] | None = None) -> tuple[subprocess.Popen[str], str]:
    proc = subprocess.Popen(
        [sys.executable, *head, "--link", "pty", *extra],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env=dict(os.environ, PYTHONUNBUFFERED="1", **(env or {})),
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
    print(f"realtime 500 Hz ({robot}) for {seconds:g} s: {summary[-1] if summary else err}")
    print(f"  telemetry received: {tel} ({tel / seconds:.1f}/s)")
    r = np.array(rtts) * 1e3
    print(f"  TIME_SYNC round trip over pty (n = {len(r)}): p50 {np.percentile(r, 50):.2f} ms, p99 {np.percentile(r, 99):.2f} ms, max {r.max():.2f} ms")


def main() -> None:
    from robots.registry import DEFAULT_ROBOT

    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=positive_seconds, default=10.0,
                    help="wall-clock seconds of the realtime pacing part (default 10)")
    parts = ap.add_mutually_exclusive_group()
    parts.add_argument("--lockstep-only", action="store_true", help="skip the realtime pacing and round-trip parts")
    parts.add_argument("--realtime-only", action="store_true", help="only the realtime pacing and round-trip parts")
    ap.add_argument("--profile", metavar="FILE", help="cProfile stats of the pty lockstep board process (first round)")
    ap.add_argument("--host-profile", metavar="FILE", help="cProfile stats of the pty lockstep host side (one extra run)")
    ap.add_argument("--rounds", type=int, default=3, help="interleaved rounds of the three lockstep rates (default 3)")
    ap.add_argument("--sim-seconds", type=positive_seconds, default=10.0,
                    help="simulated seconds of each lockstep run (default 10)")
    ap.add_argument("--robot", default=DEFAULT_ROBOT, help=f"whose board runs (default {DEFAULT_ROBOT})")
    args = ap.parse_args()
    if args.realtime_only and args.profile:
        ap.error("--profile profiles the lockstep pty board: not with --realtime-only")
    if not args.realtime_only:
        if args.rounds < 1:
            ap.error("--rounds must be at least 1")
        bench_lockstep(args.robot, args.sim_seconds, args.rounds, profile=args.profile)
        if args.host_profile:
            lockstep_pty(args.robot, args.sim_seconds, host_profile=args.host_profile)
        bench_kernels_ab(args.robot)
    if not args.lockstep_only:
        bench_realtime(args.robot, args.seconds)


if __name__ == "__main__":
    main()
