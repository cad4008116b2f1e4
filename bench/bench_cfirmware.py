"""Figures of the C firmware: Cortex-M3 image size, control-tick cost in QEMU (-icount), lockstep
speed of the native C board against the Python board, libFuzzer throughput of the C targets.

    python bench/bench_cfirmware.py [--seconds 10] [--repeat 3] [--fuzz-seconds 20] [--skip-fuzz]

* **size**: ``arm-none-eabi-size -A`` of the mps2-an385 image (flash = .text + .ARM.exidx + .data,
  RAM = .data + .bss + the 2 KB main stack + the 28-byte boot block), for the default robot and
  for generated robots of 17 and 32 servos (built with the u32-mask codec).
* **tick cost**: the image on ``qemu-system-arm -icount shift=0,sleep=on`` (one instruction per
  virtual nanosecond), a lockstep board streamed ``--seconds`` of frames; the firmware measures each
  control tick on SysTick (25 MHz of virtual time, its waits for bus bytes excluded) and reports the
  mean and max; instructions = counts x 40 (~ Cortex-M3 cycles at a CPI of ~1).
* **lockstep speed**: board seconds per wall second with nothing but the board (HELLO, then frames
  for every servo every 10 ms and ADVANCE over ``--seconds``), ``--repeat`` runs per firmware.
* **fuzz**: ``ghostshell fuzz c-wire`` and ``c-diff`` for ``--fuzz-seconds`` each: executions and exec/s.

Prints the numbers with n; the machine may be shared (say so when quoting them).
"""

from __future__ import annotations

import argparse
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from cfirmware.wire import Wire  # noqa: E402
from firmware_sim.cfirmware.build import build, codec_dir, size_of  # noqa: E402
from protocol.codec import SCHEMA_HASH  # noqa: E402
from protocol.messages import PROTOCOL_VERSION, Advance, Caps, Hello, ServoFrame, Telemetry  # noqa: E402
from robots.loader import load_robot_dir  # noqa: E402
from robots.registry import DEFAULT_ROBOT, load_robot  # noqa: E402
from support.gen_robot import write_chain_robot  # noqa: E402


def sizes(tmp: Path) -> None:
    """The default robot's image, then generated robots of 17 and 32 servos (the u32-mask codec)."""
    robots = [load_robot(DEFAULT_ROBOT)] + [load_robot_dir(write_chain_robot(tmp, n)) for n in (17, 32)]
    for robot in robots:
        elf = build("mps2", robot)
        s = size_of(elf)
        flash = s[".text"] + s.get(".ARM.exidx", 0) + s[".data"]
        ram = s[".data"] + s[".bss"] + s.get(".stack", 0) + s.get(".bootcfg", 0)
        print(f"size ({robot.name}, {robot.servo_count} servos, {codec_dir(robot).name} codec, {elf.name}): "
              f".text {s['.text']} B, .data {s['.data']} B, .bss {s['.bss']} B, stack {s.get('.stack', 0)} B -> "
              f"flash {flash} B ({flash / 1024:.1f} KB of 32), RAM {ram} B ({ram / 1024:.2f} KB of 8)")


def stream(firmware: str, seconds: float, extra: list[str], tmp: Path) -> tuple[float, str]:
    """Stream ``seconds`` of frames to a lockstep board; returns (wall seconds of the streaming, its stderr)."""
    robot = load_robot(DEFAULT_ROBOT)
    w = Wire(["--lockstep", "--firmware", firmware, *extra], tmp / f"{firmware}.stderr")
    try:
        w.send(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 0))
        w.wait(lambda: w.of(Caps), what="CAPS")
        q = robot.pose(robot.start_pose)
        mask = (1 << robot.servo_count) - 1
        end_us = int(seconds * 1e6)
        t0 = time.monotonic()
        sent = 0
        for k in range(1, end_us // 10_000 + 1):
            w.send(ServoFrame(10_000 * k, mask, q))
            sent += 1
            if sent % 20 == 0:  # keep at most ~0.2 s of frames ahead, as a host does
                w.wait(lambda: any(t.board_time_us >= 10_000 * (k - 10) for t in w.of(Telemetry)), timeout=300,
                       what="telemetry")
        w.send(Advance(end_us))
        w.wait(lambda: any(t.board_time_us >= end_us for t in w.of(Telemetry)), timeout=600, what="the end")
        wall = time.monotonic() - t0
    finally:
        w.close()
    return wall, (tmp / f"{firmware}.stderr").read_text()


def tick_cost(seconds: float, tmp: Path) -> None:
    _, err = stream("qemu", seconds, ["--icount"], tmp)
    m = re.search(r"tick cost .*?: mean (\d+), max (\d+), n (\d+)", err)
    if not m:
        print(f"tick cost: no figure in the board's stderr:\n{err[-1500:]}")
        return
    mean, mx, n = map(int, m.groups())
    print(f"tick cost (QEMU mps2-an385, -icount shift=0, lockstep, n={n} ticks): mean {mean} SysTick counts = "
          f"{mean * 40} instructions ({mean * 40 / 25e6 * 1e6:.0f} us at 25 MHz, CPI 1), max {mx * 40} instructions")


def speed(seconds: float, repeat: int, tmp: Path) -> None:
    for fw in ("python", "c"):
        rates = []
        for _ in range(repeat):
            wall, _ = stream(fw, seconds, [], tmp)
            rates.append(seconds / wall)
        print(f"lockstep speed ({fw} board, {seconds:g} board-s streamed, n={repeat}): median "
              f"{statistics.median(rates):.1f}x realtime (min {min(rates):.1f}x, max {max(rates):.1f}x)")


def fuzz(seconds: int, tmp: Path) -> None:
    for target in ("c-wire", "c-diff"):
        out = tmp / target
        r = subprocess.run([sys.executable, "-m", "host.cli", "fuzz", target, "--seconds", str(seconds), "--out",
                            str(out), "--corpus", str(out / "corpus")], capture_output=True, text=True, cwd=ROOT,
                           timeout=seconds + 300)
        line = next((ln for ln in r.stdout.splitlines() if ln.startswith(f"{target}: ") and "executions" in ln), "")
        print(f"fuzz {target} ({seconds} s, 1 job): {line.removeprefix(target + ': ') or r.stdout[-500:]}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="board seconds streamed per run (default 10)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--fuzz-seconds", type=int, default=20)
    ap.add_argument("--skip-fuzz", action="store_true")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        sizes(tmp)
        tick_cost(min(args.seconds, 4.0), tmp)
        speed(args.seconds, args.repeat, tmp)
        if not args.skip_fuzz:
            fuzz(args.fuzz_seconds, tmp)
    return 0


if __name__ == "__main__":
    sys.exit(main())
