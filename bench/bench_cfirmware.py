"""Figures of the C firmware: image sizes (Cortex-M3 stand-in, STM32F405), control-tick cost in QEMU
(-icount), lockstep speed of the native C board against the Python board, libFuzzer throughput of the C
targets.

    python bench/bench_cfirmware.py [--seconds 10] [--repeat 3] [--fuzz-seconds 20] [--skip-fuzz]
                                    [--f4-task 26]

* **size**: ``arm-none-eabi-size -A`` of the images (flash = .text + .ARM.exidx + .data, RAM = .data +
  .bss + the main stack + the 40-byte boot block): the mps2-an385 image against the small part's
  32 KB / 8 KB, for the default robot and generated robots of 17 and 32 servos (the u32-mask codec); the
  STM32F405 image (``stm32f4``) of the same robots against the part's 1024 KB flash / 128 KB SRAM.
* **tick cost**: the image on ``qemu-system-arm -icount shift=0,sleep=on`` (one instruction per
  virtual nanosecond), a lockstep board streamed ``--seconds`` of frames; the firmware measures each
  control tick on SysTick (25 MHz of virtual time, its waits for bus bytes excluded) and reports the
  mean and max; instructions = counts x 40 (~ Cortex-M3 cycles at a CPI of ~1).
* **STM32F405 tick cost**: the trace build (``stm32f4-trace``: every tick's cost as a ``K`` record) on
  ``qemu-system-arm -M netduinoplus2 -icount shift=0,sleep=on`` as the board of a lockstep task run
  (``--f4-task``, the ground truth; the host connects to that board's pty): median, p99 and worst tick over
  the run's n ticks, in instructions (SysTick counts the 168 MHz core clock; shift=0 is one instruction a
  virtual ns, so instructions = counts x 1000 / 168), each as a share of the 2 ms tick at 168 MHz (336 000
  cycles). It counts instructions, not cycles: a Cortex-M4 with 5 flash wait states (ART accelerator on) runs
  ~1-1.5 cycles an instruction. Bus waits are excluded (the firmware subtracts them).
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
from firmware_sim.cfirmware.build import BuildError, build, codec_dir, size_of  # noqa: E402
from firmware_sim.cfirmware.targets import link_overflow  # noqa: E402
from protocol.codec import SCHEMA_HASH  # noqa: E402
from protocol.messages import PROTOCOL_VERSION, Advance, Caps, Hello, ServoFrame, Telemetry  # noqa: E402
from robots.loader import load_robot_dir  # noqa: E402
from robots.registry import DEFAULT_ROBOT, load_robot  # noqa: E402
from support.gen_robot import write_chain_robot  # noqa: E402


#: the images and the budgets they are held against (KB of flash, KB of RAM)
IMAGES = (("mps2", "mps2-an385 image", 32, 8), ("stm32f4", "STM32F405 image", 1024, 128))


def sizes(tmp: Path) -> None:
    """Each image of the default robot, then of generated robots of 17 and 32 servos (the u32-mask codec)."""
    robots = [load_robot(DEFAULT_ROBOT)] + [load_robot_dir(write_chain_robot(tmp, n)) for n in (17, 32)]
    for kind, label, flash_kb, ram_kb in IMAGES:
        for robot in robots:
            try:
                elf = build(kind, robot)
            except BuildError as e:  # the part's linker script refuses an image that does not fit it
                need = link_overflow(str(e))
                if need is None:
                    raise
                print(f"size, {label} ({robot.name}, {robot.servo_count} servos, {codec_dir(robot).name} codec): "
                      f"does not fit, refused at link time: flash {need[0]} B of {flash_kb * 1024}, "
                      f"RAM {need[1]} B of {ram_kb * 1024} (the linker's region use)")
                continue
            s = size_of(elf)
            flash = s[".text"] + s.get(".ARM.exidx", 0) + s[".data"]
            ram = s[".data"] + s[".bss"] + s.get(".stack", 0) + s.get(".bootcfg", 0)
            print(f"size, {label} ({robot.name}, {robot.servo_count} servos, {codec_dir(robot).name} codec): "
                  f".text {s['.text']} B, .data {s['.data']} B, .bss {s['.bss']} B, stack {s.get('.stack', 0)} B -> "
                  f"flash {flash} B ({flash / 1024:.1f} KB of {flash_kb}, {100 * flash / (flash_kb * 1024):.1f} %), "
                  f"RAM {ram} B ({ram / 1024:.2f} KB of {ram_kb}, {100 * ram / (ram_kb * 1024):.1f} %)")


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


#: the STM32F405's core clock and control tick: the cycles one 2 ms tick has at 168 MHz
F4_HZ, TICK_CYCLES = 168_000_000, 336_000
_TICKS = re.compile(r"tick cost per tick \(cycles\): median (\d+), p99 (\d+), max (\d+), n (\d+)")


def f4_tick_cost(task: int, tmp: Path) -> None:
    """Task ``task``'s ground truth in lockstep on the STM32F405 trace image under ``-icount shift=0``."""
    from e2e.conftest import TASKS, run_e2e
    from host.link.board_process import start_board

    err = tmp / "f4-board.stderr"
    board = start_board(["--lockstep", "--firmware", "stm32f4", "--icount"], err, timeout=120)
    try:
        run_e2e(TASKS[task].ground_truth, tmp / f"f4-task{task}", task_label=f"task {task}", link=board.spec)
    finally:
        board.stop()
    m = _TICKS.search(err.read_text())
    if not m:
        print(f"STM32F405 tick cost: no figure in the board's stderr:\n{err.read_text()[-1500:]}")
        return
    med, p99, mx, n = map(int, m.groups())

    def fmt(counts: int) -> str:
        instr = counts * 1e9 / F4_HZ  # -icount shift=0: one instruction a virtual ns
        return f"{instr:,.0f} instructions ({100 * instr / TICK_CYCLES:.2f} % of the tick)"

    print(f"tick cost (STM32F405 image, QEMU netduinoplus2 -icount shift=0, lockstep task {task}, n={n} ticks): "
          f"median {fmt(med)}, p99 {fmt(p99)}, worst {fmt(mx)}; the 2 ms tick at 168 MHz is {TICK_CYCLES:,} cycles "
          f"(instructions, not cycles: ~1-1.5 cycles an instruction with flash wait states)")


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
    ap.add_argument("--f4-task", type=int, default=26, help="the task whose ticks the STM32F405 figure counts "
                                                              "(default 26)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        sizes(tmp)
        tick_cost(min(args.seconds, 4.0), tmp)
        f4_tick_cost(args.f4_task, tmp)
        speed(args.seconds, args.repeat, tmp)
        if not args.skip_fuzz:
            fuzz(args.fuzz_seconds, tmp)
    return 0


if __name__ == "__main__":
    sys.exit(main())
