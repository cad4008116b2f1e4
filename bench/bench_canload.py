"""CAN bus load of a robot's real-time traffic: computed from its layouts, and measured from a capture.

Computed: SERVO_FRAME at 100 Hz plus TELEMETRY at 50 Hz for the robot's servos (``--robot NAME``,
default the default robot, CoCo's 12; ``--servos N`` computes for N servos without a robot; the
layouts are :func:`protocol.can.layouts.can_layouts` of that count: a TELEMETRY with no fixed
layout on classic CAN, above 27 servos, is counted as its ISO-TP transfer; the hot path; TIME_SYNC at
2 Hz included; heartbeats are not sent while frames stream; SIM_STATE is emulator-only ground truth
and listed apart), on classic CAN at 1 Mbit/s and on CAN FD (1 Mbit/s arbitration, 2 or 5 Mbit/s
data phase), nominal and with worst-case bit stuffing.

Frame lengths (11-bit identifier, n data bytes):

* classic CAN (ISO 11898-1; worst-case stuffing after Davis, Burns, Bril, Lukkien, "Controller Area
  Network (CAN) schedulability analysis: Refuted, revisited and revised", Real-Time Systems 35, 2007,
  eq. 2): ``bits = 47 + 8n + floor((34 + 8n - 1) / 4)``; 47 + 8n without stuffing.
* CAN FD (ISO 11898-1:2015, Bosch CAN FD specification 1.0): at the nominal rate SOF..BRS (17 bits,
  worst case + floor(16/4) dynamic stuff bits) and CRC delimiter, ACK slot + delimiter, EOF, IFS
  (13 bits); at the data rate ESI, DLC, the data (worst case + floor((5 + 8n - 1)/4) dynamic stuff
  bits), the stuff count (4) and CRC (17 bits up to 16 data bytes, else 21) with one fixed stuff bit
  per 4 bits: ``ceil((4 + crc) / 4)``. Time = nominal bits / nominal rate + data bits / data rate.

Measured: ``--log FILE`` (a python-can log of a run: ``host_frames.log``) sums the same worst-case
bit times of every frame in the capture and divides by the board time the capture spans (from its
TELEMETRY reports, so a lockstep run measures the load it would put on a real bus). Without
``--log`` a short run is made first (``ghostshell run --task 26 --link can:slcan:pty --lockstep``; for
a robot without tasks, its tour poses as a program; CoCo's demo task is 26).

Run: ``python bench/bench_canload.py [--robot NAME | --servos N] [--log FILE] [--fd] [--no-run]``.
"""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
import tempfile
from collections import Counter
from pathlib import Path

from protocol.can.codec import Sender, encode_bulk, encode_fixed, is_fixed
from protocol.can.layouts import CanLayouts, can_layouts
from protocol.messages import Message, MsgType, TimeSyncRequest, TimeSyncReply
from protocol.testing.samples import SAMPLES, servo_frame_n, telemetry_n

NOMINAL = 1_000_000


def classic_bits(n: int, stuffing: bool = True) -> int:
    return 47 + 8 * n + ((34 + 8 * n - 1) // 4 if stuffing else 0)


def fd_time_s(n: int, data_rate: int, stuffing: bool = True, nominal: int = NOMINAL) -> float:
    arb = 17 + (16 // 4 if stuffing else 0) + 13
    crc = 17 if n <= 16 else 21
    data = 1 + 4 + 8 * n + ((5 + 8 * n - 1) // 4 if stuffing else 0) + 4 + crc + math.ceil((4 + crc) / 4)
    return arb / nominal + data / data_rate


def frame_time_s(n: int, fd: bool, data_rate: int, stuffing: bool = True) -> float:
    return fd_time_s(n, data_rate, stuffing) if fd else classic_bits(n, stuffing) / NOMINAL


def _isotp_frames(sdu_len: int, fd: bool) -> list[int]:
    """Frame data lengths of one ISO-TP transfer (frames padded to 8 bytes, FD to 64), flow control included."""
    size = 64 if fd else 8
    if sdu_len <= size - (2 if fd else 1):
        return [size]
    first = size - (2 if sdu_len > 4095 else 2)  # FF: 2 PCI bytes
    cf = math.ceil((sdu_len - first) / (size - 1))
    return [size] * (1 + cf) + [size]  # first frame, consecutive frames, flow control


def _lengths(msg: Message, fd: bool, sender: str, layouts: CanLayouts) -> list[int]:
    """Data lengths of the frames carrying ``msg``: its fixed frames, or its ISO-TP transfer."""
    if is_fixed(msg, fd, layouts):
        return [len(f.data) for f in encode_fixed(msg, 1, 1, fd, sender, layouts)]
    return _isotp_frames(len(encode_bulk(msg, 1, layouts.schema)), fd)


def computed(fd: bool, data_rate: int, servos: int = 12) -> list[tuple[str, float, int, float, float]]:
    """(what, Hz, frames per message, nominal load, worst-case load) rows (load as a fraction of the bus)."""
    rows = []
    layouts = can_layouts(servos)
    tel = "TELEMETRY (board)" if is_fixed(telemetry_n(servos), fd, layouts) else "TELEMETRY (board, ISO-TP)"
    traffic = [
        ("SERVO_FRAME (host)", 100.0, _lengths(servo_frame_n(servos), fd, Sender.HOST, layouts)),
        (tel, 50.0, _lengths(telemetry_n(servos), fd, Sender.BOARD, layouts)),
        ("TIME_SYNC req+reply", 2.0, _lengths(TimeSyncRequest(1), fd, Sender.HOST, layouts)
         + _lengths(TimeSyncReply(1, 2, 3), fd, Sender.BOARD, layouts)),
    ]
    for what, hz, frames in traffic:
        nom = sum(frame_time_s(n, fd, data_rate, False) for n in frames) * hz
        worst = sum(frame_time_s(n, fd, data_rate, True) for n in frames) * hz
        rows.append((what, hz, len(frames), nom, worst))
    sim = _isotp_frames(len(encode_bulk(SAMPLES[MsgType.SIM_STATE], 1, layouts.schema)), fd)
    rows.append(("SIM_STATE (emulator, ISO-TP)", 50.0, len(sim),
                 sum(frame_time_s(n, fd, data_rate, False) for n in sim) * 50,
                 sum(frame_time_s(n, fd, data_rate, True) for n in sim) * 50))
    return rows


def print_computed(servos: int = 12, who: str = "") -> None:
    for fd, rate, label in ((False, NOMINAL, "classic CAN, 1 Mbit/s"),
                            (True, 2_000_000, "CAN FD, 1 Mbit/s arbitration / 2 Mbit/s data"),
                            (True, 5_000_000, "CAN FD, 1 Mbit/s arbitration / 5 Mbit/s data")):
        print(f"\ncomputed: {who}{servos} servos, {label}")
        print(f"  {'traffic':<30} {'Hz':>5} {'frames':>6} {'nominal':>9} {'worst':>9}")
        tot_n = tot_w = 0.0
        for what, hz, nf, nom, worst in computed(fd, rate, servos):
            print(f"  {what:<30} {hz:5.0f} {nf:6d} {100 * nom:8.2f}% {100 * worst:8.2f}%")
            if "SIM_STATE" not in what:
                tot_n, tot_w = tot_n + nom, tot_w + worst
        print(f"  {'total (without SIM_STATE)':<30} {'':5} {'':6} {100 * tot_n:8.2f}% {100 * tot_w:8.2f}%")


def measure(path: Path, data_rate: int = 2_000_000, servos: int | None = None) -> None:
    from host.link.canlog import iter_can_log
    from protocol.can import CanItem
    from protocol.messages import Telemetry

    busy = 0.0
    by_kind: Counter[str] = Counter()
    frames = 0
    t_min = t_max = None
    for e in iter_can_log(path, servos=servos):
        frames += 1
        dt = frame_time_s(len(e.frame.data), e.frame.is_fd, data_rate, True)
        busy += dt
        by_kind[(e.dbc_name or "UNKNOWN").rsplit("_N", 1)[0]] += dt  # type: ignore[assignment]
        for it in e.items:
            if isinstance(it, CanItem) and isinstance(it.msg, Telemetry):
                t = it.msg.board_time_us * 1e-6
                t_min = t if t_min is None else min(t_min, t)
                t_max = t if t_max is None else max(t_max, t)
    if t_min is None or t_max is None or t_max <= t_min:
        print(f"\nmeasured: {path}: no telemetry to time the capture by")
        return
    span = t_max - t_min
    print(f"\nmeasured from {path}: {frames} frames over {span:.2f} s of board time (FD data phase at {data_rate // 1_000_000} Mbit/s)")
    for k, v in sorted(by_kind.items(), key=lambda kv: -kv[1]):
        print(f"  {k:<28} {100 * v / span:8.2f}%")
    print(f"  {'total (worst-case stuffing)':<28} {100 * busy / span:8.2f}%")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--log", type=Path, help="a python-can log of a run (host_frames.log)")
    ap.add_argument("--no-run", action="store_true", help="only the computed numbers unless --log is given")
    ap.add_argument("--fd", action="store_true", help="make the capture run on CAN FD (can:slcan:pty?fd=1)")
    who = ap.add_mutually_exclusive_group()
    who.add_argument("--robot", default=None, metavar="NAME", help="the robot (a name or a folder; default: the default robot)")
    who.add_argument("--servos", type=int, default=None, metavar="N", help="compute for N servos (no robot, no run)")
    ap.add_argument("--robots-dir", default=None, metavar="DIR", help="search this folder for --robot first")
    args = ap.parse_args()
    robot = None
    if args.servos is not None:
        servos, label = args.servos, ""
        if not 1 <= servos <= 32:
            ap.error(f"--servos {servos}: the wire carries 1 to 32 servos")
    else:
        from robots.description import RobotDataError
        from robots.registry import load_robot

        try:
            robot = load_robot(args.robot, args.robots_dir)
        except RobotDataError as e:
            print(f"bench_canload: {e}", file=sys.stderr)
            return 2
        servos, label = robot.servo_count, f"{robot.name}, "
    print_computed(servos, label)
    log = args.log
    if log is None and not args.no_run and robot is not None:
        out = Path(tempfile.mkdtemp(prefix="canload-"))
        link = "can:slcan:pty?fd=1" if args.fd else "can:slcan:pty"
        task = robot.demo_task  # CoCo: task 26
        what = ["--task", str(task)] if task is not None else ["--xml", "".join(f'<pose name="{p}"/>' for p in robot.tour)]
        cmd = [sys.executable, "-m", "host.cli", "run", *what, "--robot", str(robot.root), "--link", link,
               "--lockstep", "--no-live", "--out", str(out)]
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
        if r.returncode != 0:
            print(f"the capture run failed:\n{r.stdout[-1000:]}\n{r.stderr[-1000:]}")
            return 1
        log = out / "host_frames.log"
    if log is not None:
        measure(log, servos=servos if args.servos is not None else None)
    return 0


if __name__ == "__main__":
    sys.exit(main())
