"""SocketCAN beside the pty: frame round trip, and bus load measured from a candump capture.

This machine's kernel has no ``vcan``; the SocketCAN parts run inside User-Mode Linux (one boot,
``host/tools/vcan/uml.py``) unless ``vcan0`` exists natively. The pty numbers are taken in the same
kernel as the CAN ones (inside UML when UML is used), so the two columns compare like with like;
UML makes every system call several times dearer than on the host, so absolute numbers are
upper bounds for a native kernel.

Sections (each printed as p50/p99/max in microseconds):

* ``raw``: one 8-byte frame to an echo process and back — python-can ``socketcan`` on vcan0
  (send + recv through the kernel's CAN stack, CAN_RAW sockets) beside 8 bytes over a pty pair
  (the serial transport's bottom layer, no COBS);
* ``session``: the whole link stack (BoardClient, transport, board subprocess) for ``pty``,
  ``can:socketcan:vcan0`` (classic: TIME_SYNC request 1 frame, reply 3 parts; TELEMETRY 17) and
  ``can:socketcan:vcan0?fd=1``: TIME_SYNC round trip (host t4 - t1), and a SERVO_FRAME due at the
  next tick + ADVANCE by one tick -> the telemetry that reports it applied (telemetry 500 Hz:
  one report per tick). The board runs in lockstep: a realtime board (500 Hz MuJoCo) inside a
  UML guest pinned to one shared CPU overruns its ticks and the CAN handshake's ISO-TP transfers
  time out, so realtime numbers inside UML would measure the starved CPU, not the link. Then
  2 s of board time of 100 Hz servo frames + 50 Hz telemetry are captured with candump and the
  bus load is computed from the capture (``bench/bench_canload.py --log``: worst-case bit times
  over the board time the capture spans; exact stuffing for classic frames here);
* ``latency``: ``bench/bench_latency.py`` (token -> servo over paper tasks, realtime board) for
  ``pty`` and ``can:socketcan:vcan0`` on ``--tasks`` (default 3,5,12);
* ``load``: a ``candump -L`` capture of a 100 Hz x 12-servo frame stream plus 50 Hz telemetry-sized
  frames, read back with ``can.CanutilsLogReader``; the bus load on 1 Mbit/s classic CAN is the sum
  of each captured frame's exact on-wire length (bit stuffing computed on the frame's real bits,
  see :func:`classic_frame_bits`) over the capture's duration.

Run: ``python bench/bench_can.py [--n 500] [--seconds 2] [--tasks 3,5,12] [--skip latency,...]
[--where auto|native|uml]``.
Numbers are printed, never asserted.
"""

from __future__ import annotations

import argparse
import os
import select
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT))

from support.uml import default_env, native_vcan, run_in_uml, socketcan_skip_reason  # noqa: E402

CHANNEL = "vcan0"
TICK_US = 2_000  # the board's 500 Hz control tick

_CAN_ECHO = r"""
import can, sys
bus = can.Bus(interface="socketcan", channel=sys.argv[1])
print("ready", flush=True)
while True:
    m = bus.recv()
    if m.arbitration_id == 0x7FE:
        break
    bus.send(can.Message(arbitration_id=m.arbitration_id + 1, data=m.data, is_extended_id=False))
bus.shutdown()
"""

_PTY_ECHO = r"""
import os, sys
fd = os.open(sys.argv[1], os.O_RDWR | os.O_NOCTTY)
import tty; tty.setraw(fd)
print("ready", flush=True)
while True:
    data = os.read(fd, 64)
    if not data or data == b"quit":
        break
    os.write(fd, data)
"""


def _pct(name: str, xs: list[float]) -> str:
    a = np.asarray(xs)
    return (f"{name:<62} n={len(a):4d}  p50={np.percentile(a, 50):7.0f} us  p99={np.percentile(a, 99):7.0f} us"
            f"  max={a.max():7.0f} us")


def _wait_ready(proc: subprocess.Popen[str]) -> None:
    assert proc.stdout is not None
    ready, _, _ = select.select([proc.stdout], [], [], 30)
    if not ready or proc.stdout.readline().strip() != "ready":
        raise RuntimeError("echo process did not start")


def raw_can_round_trip(n: int, channel: str = CHANNEL) -> list[float]:
    """``n`` send -> echo -> receive times (us) of 8-byte classic frames on ``channel``."""
    import can

    echo = subprocess.Popen([sys.executable, "-c", _CAN_ECHO, channel], stdout=subprocess.PIPE, text=True)
    bus = can.Bus(interface="socketcan", channel=channel, can_filters=[{"can_id": 0x124, "can_mask": 0x7FF}])
    try:
        _wait_ready(echo)
        out = []
        for i in range(n):
            t0 = time.perf_counter_ns()
            bus.send(can.Message(arbitration_id=0x123, data=i.to_bytes(8, "little"), is_extended_id=False))
            reply = bus.recv(timeout=2)
            out.append((time.perf_counter_ns() - t0) / 1e3)
            assert reply is not None and int.from_bytes(reply.data, "little") == i
        bus.send(can.Message(arbitration_id=0x7FE, data=b"", is_extended_id=False))
        echo.wait(timeout=10)
        return out
    finally:
        bus.shutdown()
        if echo.poll() is None:
            echo.kill()


def raw_pty_round_trip(n: int) -> list[float]:
    """``n`` write -> echo -> read times (us) of 8 bytes over a raw pty pair."""
    import tty

    master, slave = os.openpty()
    tty.setraw(master)
    echo = subprocess.Popen([sys.executable, "-c", _PTY_ECHO, os.ttyname(slave)], stdout=subprocess.PIPE, text=True)
    try:
        _wait_ready(echo)
        out = []
        for i in range(n):
            msg = i.to_bytes(8, "little")
            t0 = time.perf_counter_ns()
            os.write(master, msg)
            got = b""
            while len(got) < 8:
                got += os.read(master, 8 - len(got))
            out.append((time.perf_counter_ns() - t0) / 1e3)
            assert got == msg
        os.write(master, b"quit")
        echo.wait(timeout=10)
        return out
    finally:
        if echo.poll() is None:
            echo.kill()
        os.close(master)
        os.close(slave)


def _crc15(bits: list[int]) -> int:
    """CAN 2.0 CRC-15 (polynomial 0x4599) over the unstuffed bits SOF..data (ISO 11898-1, 10.4.2.6)."""
    crc = 0
    for b in bits:
        nxt = b ^ ((crc >> 14) & 1)
        crc = (crc << 1) & 0x7FFF
        if nxt:
            crc ^= 0x4599
    return crc


def classic_frame_bits(can_id: int, data: bytes, extended: bool = False) -> int:
    """Exact on-wire bits of a classic CAN data frame, stuff bits included, plus 3 bits interframe space.

    Layout (ISO 11898-1): SOF, identifier (11 or 11+SRR+IDE+18), RTR, IDE/r1, r0, DLC(4), data,
    CRC-15 — the stuffed part — then CRC delimiter, ACK slot, ACK delimiter, EOF(7), IFS(3) = 13
    unstuffed bits. A stuff bit follows every 5 equal consecutive bits (the stuff bit counts in the
    next run). Hand-written: no maintained Python library computes stuffed CAN frame lengths.
    """
    def field(value: int, width: int) -> list[int]:
        return [(value >> (width - 1 - k)) & 1 for k in range(width)]

    if extended:
        bits = [0] + field(can_id >> 18, 11) + [1, 1] + field(can_id & 0x3FFFF, 18) + [0, 0, 0]
    else:
        bits = [0] + field(can_id, 11) + [0, 0, 0]
    bits += field(len(data), 4)
    for byte in data:
        bits += field(byte, 8)
    bits += field(_crc15(bits), 15)
    stuffed, run, last = 0, 0, -1
    for b in bits:
        run = run + 1 if b == last else 1
        last = b
        if run == 5:
            stuffed += 1
            last, run = 1 - b, 1  # the stuff bit has the opposite level and starts a new run
    return len(bits) + stuffed + 13


def measure_bus_load(seconds: float, capture_path: Path, channel: str = CHANNEL) -> str:
    """Capture a 100 Hz servo-frame + 50 Hz telemetry stream with candump; the measured bus load."""
    import can

    from support.candump import CandumpCapture

    bus = can.Bus(interface="socketcan", channel=channel)
    try:
        with CandumpCapture(channel, capture_path) as capture:
            t0 = time.perf_counter()
            k = 0
            while True:  # 10 ms grid: per tick 3 frames of 4 servos (8 bytes each); telemetry every 2nd
                due = t0 + k * 0.01
                now = time.perf_counter()
                if due > t0 + seconds:
                    break
                if due > now:
                    time.sleep(due - now)  # pacing a traffic generator, not synchronisation
                for part in range(3):
                    bus.send(can.Message(arbitration_id=0x180 + part, data=os.urandom(8), is_extended_id=False))
                if k % 2 == 0:
                    for part in range(2):
                        bus.send(can.Message(arbitration_id=0x280 + part, data=os.urandom(8), is_extended_id=False))
                k += 1
    finally:
        bus.shutdown()
    msgs = capture.messages()
    span = msgs[-1].timestamp - msgs[0].timestamp if len(msgs) > 1 else 0.0
    bits = sum(classic_frame_bits(m.arbitration_id, bytes(m.data), m.is_extended_id) for m in msgs)
    worst = sum(_worst_case_bits(len(m.data)) for m in msgs)
    return (f"captured {len(msgs)} frames in {span:.2f} s ({len(msgs) / span:.0f} frames/s) -> {bits / span / 1e3:.1f} kbit/s "
            f"= {bits / span / 1e6 * 100:.1f} % of 1 Mbit/s classic CAN (exact stuffing; worst case "
            f"{worst / span / 1e6 * 100:.1f} %); capture {capture_path}")


def _worst_case_bits(dlc: int) -> int:
    """Worst-case classic 11-bit frame length incl. 3-bit IFS: 47 + 8n + floor((34 + 8n - 1) / 4) (Davis et al. 2007)."""
    return 47 + 8 * dlc + (34 + 8 * dlc - 1) // 4


async def _session(link: str, n: int, capture: Path | None) -> None:
    from host.link import BoardClient
    from host.link.board_process import start_board
    from protocol.messages import ServoFrame
    from robots.registry import load_robot

    from support.candump import CandumpCapture

    neutral = load_robot().servos.neutral
    board = start_board(["--lockstep", "--telemetry-rate", "500"], link=link)
    try:
        async with await BoardClient.connect(board.spec, handshake_timeout=20.0, reply_timeout=5.0) as c:
            rtt = []
            for _ in range(n):
                t1, _t2, _t3, t4 = await c.sync_once(timeout=5.0)
                rtt.append(t4 - t1)
            lat = []
            for _ in range(n):
                t_send = time.monotonic()
                due = c.board_now_estimate() + TICK_US
                seq = c.send_frame(ServoFrame(due, 0xFFF, neutral))
                await c.advance(due)
                await c.wait_for(lambda t, s=seq: t.last_applied_seq == s, 5.0)
                lat.append((time.monotonic() - t_send) * 1e6)
            print(_pct(f"TIME_SYNC round trip, {link}", rtt), flush=True)
            print(_pct(f"frame + ADVANCE -> telemetry shows it applied, {link}", lat), flush=True)
    finally:
        board.stop()
    if capture is None:
        return
    board = start_board(["--lockstep"], link=link)  # default 50 Hz telemetry
    try:
        async with await BoardClient.connect(board.spec, handshake_timeout=20.0, reply_timeout=5.0) as c:
            if True:  # 2 s of board time: 100 Hz servo frames + 50 Hz telemetry
                start = c.board_now_estimate()
                with CandumpCapture(CHANNEL, capture):
                    for k in range(1, 201):
                        c.send_frame(ServoFrame(start + 10_000 * k, 0xFFF, neutral))
                        if k % 10 == 0:
                            await c.advance(start + 10_000 * k)
                            await c.wait_for(lambda t, u=start + 10_000 * k: t.board_time_us >= u, 5.0)
    finally:
        board.stop()


def _board_span_s(path: Path) -> float:
    """Board time (s) a capture spans, from the TELEMETRY reports in it (protocol's CAN decoder)."""
    import can

    from protocol.can import CanDecoder, CanFrame, CanItem
    from protocol.messages import Telemetry

    dec = CanDecoder(1, receiver="host")
    times = []
    for m in can.CanutilsLogReader(path):
        for item in dec.feed(CanFrame(m.arbitration_id, bytes(m.data), m.is_fd, m.is_extended_id, m.is_remote_frame)):
            if isinstance(item, CanItem) and isinstance(item.msg, Telemetry):
                times.append(item.msg.board_time_us)
    return (max(times) - min(times)) / 1e6 if len(times) > 1 else float("nan")


def session_round_trips(n: int, out: Path) -> None:
    """TIME_SYNC RTT and frame -> applied over pty, classic SocketCAN and CAN FD; the board-traffic capture."""
    import asyncio

    for link, cap in (("pty", None), (f"can:socketcan:{CHANNEL}", out / "board_run.log"),
                      (f"can:socketcan:{CHANNEL}?fd=1", out / "board_run_fd.log")):
        asyncio.run(_session(link, n, cap))
    for cap in (out / "board_run.log", out / "board_run_fd.log"):
        msgs = list(__import__("can").CanutilsLogReader(cap))
        span = _board_span_s(cap)
        classic = [m for m in msgs if not m.is_fd]
        exact = sum(classic_frame_bits(m.arbitration_id, bytes(m.data)) for m in classic)
        note = (f"; classic frames at their exact stuffed length: {exact / span / 1e4:.2f} % of 1 Mbit/s"
                if len(classic) == len(msgs) else "")
        print(f"capture {cap.name}: {len(msgs)} frames over {span:.2f} s of board time{note}; worst case "
              f"(python bench/bench_canload.py --log {cap} --no-run):", flush=True)
        proc = subprocess.run([sys.executable, str(ROOT / "bench" / "bench_canload.py"), "--log", str(cap), "--no-run"],
                              capture_output=True, text=True, check=False)
        lines = proc.stdout.splitlines()
        start = next((i for i, ln in enumerate(lines) if "measured" in ln.lower()), len(lines))
        for line in lines[start:] or proc.stderr.splitlines()[-3:]:
            print("  bench_canload:", line.rstrip(), flush=True)


def token_latency(tasks: str, out: Path) -> None:
    """bench_latency.py over pty and SocketCAN, realtime, on ``tasks``: its summary lines."""
    for link in ("pty", f"can:socketcan:{CHANNEL}"):
        proc = subprocess.run([sys.executable, str(ROOT / "bench" / "bench_latency.py"), "--tasks", tasks, "--link", link,
                               "--out", str(out / f"latency_{link.split(':')[0]}")],
                              capture_output=True, text=True, check=False)
        keep = [ln for ln in proc.stdout.splitlines() if "token -> servo" in ln or "ready -> servo" in ln]
        print(f"token -> servo over {link} (tasks {tasks}, realtime):", flush=True)
        for ln in keep or proc.stderr.splitlines()[-5:]:
            print("  " + ln.strip(), flush=True)


def inside(args: argparse.Namespace) -> None:
    print(f"kernel {os.uname().release}, {'UML' if os.environ.get('GHOSTSHELL_IN_UML') else 'native'}", flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    skip = set(args.skip.split(",")) if args.skip else set()
    if "raw" not in skip:
        print(_pct("raw 8-byte frame round trip, SocketCAN vcan0", raw_can_round_trip(args.n)), flush=True)
        print(_pct("raw 8-byte round trip, pty pair", raw_pty_round_trip(args.n)), flush=True)
    if "load" not in skip:
        print("synthetic bus load (100 Hz x 3 + 50 Hz x 2 classic frames):",
              measure_bus_load(args.seconds, out / "load.log"), flush=True)
    if "session" not in skip:
        session_round_trips(max(args.n // 5, 30), out)
    if "latency" not in skip:
        token_latency(args.tasks, out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=500, help="round trips per measurement")
    ap.add_argument("--seconds", type=float, default=2.0, help="length of the bus-load capture")
    ap.add_argument("--where", choices=("auto", "native", "uml"), default="auto")
    ap.add_argument("--tasks", default="3,5,12", help="paper tasks for the token -> servo section")
    ap.add_argument("--skip", default="", help="comma-separated sections to skip: raw,load,session,latency")
    ap.add_argument("--out", default=None, help="folder for captures (default: a temporary folder)")
    ap.add_argument("--inside", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.out is None:
        import tempfile

        args.out = tempfile.mkdtemp(prefix="bench_can_")
    if args.inside or args.where == "native" or (args.where == "auto" and native_vcan(CHANNEL)):
        inside(args)
        return 0
    reason = socketcan_skip_reason()
    if reason is not None:
        print(f"bench_can: nothing measured: {reason}")
        return 0
    run_dir = Path(args.out) / "uml"
    t0 = time.monotonic()
    from host.progress import status

    with status("bench_can: booting User-Mode Linux and measuring inside it (the results print when it is done)"):
        result = run_in_uml(
            [sys.executable, str(Path(__file__).resolve()), "--inside", "--n", str(args.n), "--seconds",
             str(args.seconds), "--out", str(args.out), "--tasks", args.tasks, "--skip", args.skip],
            run_dir=run_dir,
            keep=[Path(args.out)],
            env=default_env({"GHOSTSHELL_IN_UML": "1"}),
            timeout=900,
        )
    print(result.stdout, end="")
    if result.returncode != 0:
        print(result.describe(), file=sys.stderr)
    print(f"(one UML boot, {time.monotonic() - t0:.1f} s wall)")
    return result.returncode


if __name__ == "__main__":
    sys.exit(main())
