"""The servo-bus cycle a board runs every control tick: one sync write of the goals + one sync read of
the present values, per protocol, on the plant over a real pty, driven by the vendors' own SDKs.

    PYTHONPATH=. python bench/bench_servo_bus.py [--cycles 2000] [--protocols sts,dxl2] [--robots arm,coco]

Per protocol (Feetech STS: goal 2 B at 42, present position/speed/load 6 B at 56; Dynamixel Protocol
2.0: goal 4 B at 116, present current/velocity/position 10 B at 126) and robot (arm: 6 servos, coco:
12), the plant (``python -m firmware_sim.plant``, realtime, the servos at BAUD) answers on a pty, and
``scservo_sdk`` / ``dynamixel_sdk`` run CYCLES cycles of GroupSyncWrite + GroupSyncRead.

Printed per case: n cycles; **bus** = the plant's modelled wire time per cycle (the bytes both ways at
BAUD, 10 bits a byte, each servo's return delay — 0 here, as LeRobot configures them; mean and max us)
and the highest control rate the wire allows (1 / max bus time); **with USB** = the same with one
USB-serial latency-timer expiry per cycle (FTDI: 1 ms once set to 1, 16 ms by default: the rate a PC
reaches through such an adapter); **pty** = the cycle's wall time here (mean, p99 us): the plant
releases each status packet at its modelled end time, so this is the bus time plus this machine's pty
and Python overheads, not a property of the wire.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from robots.hardware import STEP_CENTRE  # noqa: E402
from robots.registry import load_robot  # noqa: E402

USB_LATENCY_US = 1000.0  # an FTDI adapter's latency timer set to 1 ms (LeRobot does; the default is 16 ms)


@dataclass(frozen=True)
class Layout:
    goal_addr: int
    goal_len: int
    present_addr: int
    present_len: int


LAYOUTS = {"sts": Layout(42, 2, 56, 6), "dxl2": Layout(116, 4, 126, 10)}
#: (torque enable, return delay time) addresses: STS 40 / 7, Dynamixel X 64 / 9 (EEPROM: torque off to write)
SETUP = {"sts": (40, 7), "dxl2": (64, 9)}


def _sdk(protocol: str) -> Any:
    if protocol == "sts":
        import scservo_sdk as sdk
        import scservo_sdk.port_handler as ph

        ph.LATENCY_TIMER = 16  # the SDK's default read-timeout slack (ms)
        return sdk, sdk.PacketHandler(0)
    import dynamixel_sdk as sdk
    import dynamixel_sdk.port_handler as ph

    ph.LATENCY_TIMER = 16
    return sdk, sdk.PacketHandler(2.0)


def _start_plant(robot: str, protocol: str, baud: int) -> tuple[subprocess.Popen[str], str]:
    proc = subprocess.Popen([sys.executable, "-m", "firmware_sim.plant", "--robot", robot, "--protocol", protocol,
                             "--baud", str(baud)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, PYTHONUNBUFFERED="1"))
    assert proc.stdout is not None
    line = proc.stdout.readline().strip()
    if not line.startswith("plant: servo bus on "):
        proc.kill()
        raise SystemExit(f"bench_servo_bus: the plant did not start ({protocol}): {line!r} {proc.communicate()[1][-500:]}")
    return proc, line.removeprefix("plant: servo bus on ")


def _stop_plant(proc: subprocess.Popen[str]) -> tuple[float, float]:
    """SIGTERM the plant; its modelled (mean, max) bus time per tick (us) from its exit line."""
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=30)
    m = re.search(r"bus time per tick mean (\d+) us, max (\d+) us", err)
    if not m:
        raise SystemExit(f"bench_servo_bus: no bus-time line from the plant: {err[-500:]}")
    return float(m.group(1)), float(m.group(2))


def run_case(robot_name: str, protocol: str, cycles: int, baud: int) -> dict[str, Any]:
    robot = load_robot(robot_name)
    ids = [s.id for s in robot.servos]
    lay = LAYOUTS[protocol]
    sdk, packet = _sdk(protocol)
    proc, port_name = _start_plant(robot_name, protocol, baud)
    try:
        port = sdk.PortHandler(port_name)
        if not port.openPort() or not port.setBaudRate(baud):
            raise SystemExit(f"bench_servo_bus: cannot open {port_name} at {baud}")
        torque, delay = SETUP[protocol]
        for i in ids:  # return delay 0, as LeRobot sets its servos up (Dynamixel ships with 250 = 500 us)
            packet.write1ByteTxRx(port, i, torque, 0)
            packet.write1ByteTxRx(port, i, delay, 0)
            packet.write1ByteTxRx(port, i, torque, 1)
        writer = sdk.GroupSyncWrite(port, packet, lay.goal_addr, lay.goal_len)
        reader = sdk.GroupSyncRead(port, packet, lay.present_addr, lay.present_len)
        for i in ids:
            reader.addParam(i)
        goal = list(STEP_CENTRE.to_bytes(lay.goal_len, "little"))
        times: list[float] = []
        failed = 0
        for _ in range(cycles):
            t0 = time.perf_counter()
            writer.clearParam()
            for i in ids:
                writer.addParam(i, goal)
            writer.txPacket()
            ok = reader.txRxPacket() == sdk.COMM_SUCCESS
            times.append(time.perf_counter() - t0)
            failed += not ok
        port.closePort()
    finally:
        bus_mean, bus_max = _stop_plant(proc)
    a = np.asarray(times) * 1e6
    return {"robot": robot_name, "servos": len(ids), "protocol": protocol, "n": cycles, "failed": failed,
            "bus_mean_us": bus_mean, "bus_max_us": bus_max, "wall_mean_us": float(a.mean()),
            "wall_p99_us": float(np.percentile(a, 99))}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cycles", type=int, default=2000)
    p.add_argument("--protocols", default="sts,dxl2")
    p.add_argument("--robots", default="arm,coco")
    p.add_argument("--baud", type=int, default=1_000_000)
    args = p.parse_args(argv)
    print(f"servo-bus cycle (sync write goals + sync read present) at {args.baud} baud, plant on a pty, "
          f"load {os.getloadavg()[0]:.2f}")
    print(f"{'protocol':8} {'servos':>6} {'n':>6} {'bus mean':>9} {'bus max':>8} {'max rate':>9} "
          f"{'w/ USB 1ms':>10} {'pty mean':>9} {'pty p99':>8} failed")
    for protocol in args.protocols.split(","):
        for robot in args.robots.split(","):
            r = run_case(robot, protocol, args.cycles, args.baud)
            rate = 1e6 / r["bus_max_us"] if r["bus_max_us"] else float("inf")
            usb = 1e6 / (r["bus_max_us"] + USB_LATENCY_US)
            print(f"{protocol:8} {r['servos']:>6} {r['n']:>6} {r['bus_mean_us']:>6.0f} us {r['bus_max_us']:>5.0f} us "
                  f"{rate:>6.0f} Hz {usb:>7.0f} Hz {r['wall_mean_us']:>6.0f} us {r['wall_p99_us']:>5.0f} us {r['failed']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
