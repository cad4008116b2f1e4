"""``python -m firmware_sim.cfirmware build|targets``: build the C firmware for a robot and a part, or list the parts.

``build --robot NAME --target native|mps2|stm32f4 [--out DIR] [--calibrated] [--define NAME=N]`` builds the firmware
(:func:`firmware_sim.cfirmware.build.build`, cached) and writes it into ``--out`` (default
``./firmware/ROBOT-TARGET/``): an ARM target's image as ``gs_firmware.elf``, ``.bin`` (raw, from the
start of flash) and ``.hex`` (Intel HEX); ``native`` the executable ``gs_firmware``. It prints the
image's flash and RAM use against the part's budget (:mod:`firmware_sim.cfirmware.targets`), and
writes nothing when the robot does not fit: more servos than the target drives, or flash or RAM over
budget (the port's linker script refuses such an image: the line gives the linker's numbers,
:func:`firmware_sim.cfirmware.targets.link_overflow`), each one line naming the numbers. ``targets`` prints the table.

``ghostshell firmware build|targets`` runs this module (the host never imports firmware_sim), with
``GHOSTSHELL_FIRMWARE_PROG`` naming it ``ghostshell firmware`` in its lines.

Exit status (the ``ghostshell`` table): 0 built and written; 1 the robot does not fit the target, the
toolchain is missing (the line is the install command) or the compiler failed; 2 usage or bad input
(an unknown robot or target, a malformed robot, an ``--out`` that cannot be a folder); 130 interrupted
(SIGINT or SIGTERM: the build's compiler is stopped and nothing is written).
"""

from __future__ import annotations

import argparse
import math
import os
import re
import shutil
import signal
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from types import FrameType
from typing import NoReturn

from firmware_sim.cfirmware.targets import TARGETS, Target, image_use, link_overflow

__all__ = ["PROG_ENV", "build_parser", "main"]

#: the name the lines show: ``ghostshell firmware`` sets it when it runs this module for the user
PROG_ENV = "GHOSTSHELL_FIRMWARE_PROG"
OK, FAILED, USAGE, INTERRUPTED = 0, 1, 2, 130


def _prog() -> str:
    return os.environ.get(PROG_ENV) or "python -m firmware_sim.cfirmware"


class _OneLineParser(argparse.ArgumentParser):
    """A usage error is one line, ``PROG: error: WHY (PROG --help: usage)``, exit status 2 (as
    ``host.cli.OneLineParser``; firmware_sim imports nothing of the host)."""

    def error(self, message: str) -> NoReturn:
        self.exit(USAGE, f"{self.prog}: error: {message} ({self.prog} --help: usage)\n")


class _Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the command runs, as Ctrl-C raises KeyboardInterrupt."""


def _on_sigterm(signum: int, frame: FrameType | None) -> None:
    raise _Terminated()


def _say(message: str) -> None:
    """One error line, ``PROG: message``, on stderr."""
    print(f"{_prog()}: {message}", file=sys.stderr, flush=True)


def _b(n: int) -> str:
    """``32 768`` (bytes, thousands separated by a space)."""
    return f"{n:,}".replace(",", " ")


def _percent(n: int, budget: int) -> str:
    """``99.9 %``: rounded down, so an image that fits never reads 100.0 %."""
    return f"{math.floor(1000 * n / budget) / 10:.1f} %"


def _out_dir(text: str) -> Path:
    """``--out``: a folder name; an empty one (``--out ""``, which would write into the current folder) is refused."""
    if not text.strip():
        raise argparse.ArgumentTypeError("give a folder (an empty name would write into the current folder)")
    return Path(text)


def _define(text: str) -> tuple[str, int]:
    """``NAME=N`` -> (NAME, N): an upper-case C name and a non-negative integer (decimal or 0x...)."""
    name, sep, value = text.partition("=")
    if not sep or re.fullmatch(r"[A-Z_][A-Z0-9_]*", name) is None:
        raise argparse.ArgumentTypeError(f"expected NAME=N with an upper-case C name (GS_HSE_HZ=12000000), got {text!r}")
    try:
        v = int(value.replace("_", ""), 0)
    except ValueError:
        v = -1
    if v < 0:
        raise argparse.ArgumentTypeError(f"{name}: expected a non-negative integer, got {value!r}")
    return name, v


def build_parser() -> argparse.ArgumentParser:
    """The parser of ``build`` and ``targets`` (prog from ``$GHOSTSHELL_FIRMWARE_PROG``)."""
    from robots.registry import DEFAULT_ROBOT, robots_dir_arg

    p = _OneLineParser(prog=_prog(), description="Build the C firmware of a robot for a part, or list the parts.")
    sub = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    b = sub.add_parser("build", help="build the firmware of a robot for a target and write it into --out",
                       description="Build the C firmware of a robot for a target part; write gs_firmware.elf, .bin and "
                                   ".hex (native: the executable) into --out and print the flash and RAM it uses "
                                   "against the part's budget. A robot that does not fit is refused (exit 1), "
                                   "nothing written.")
    b.add_argument("--robot", default=DEFAULT_ROBOT, metavar="NAME",
                   help=f"the robot: a name (ghostshell robots list) or a robot folder (default {DEFAULT_ROBOT})")
    b.add_argument("--robots-dir", default=None, metavar="DIR", type=robots_dir_arg,
                   help="a folder of robots searched before the user robot folder and the built-in robots")
    b.add_argument("--target", required=True, choices=list(TARGETS), help="the part (the targets action lists them)")
    b.add_argument("--out", type=_out_dir, default=None, metavar="DIR",
                   help="folder to write the files into (default ./firmware/ROBOT-TARGET/)")
    b.add_argument("--define", dest="defines", action="append", type=_define, default=[], metavar="NAME=N",
                   help="a port's build setting, -DNAME=N (repeatable; an unsigned integer), e.g. the STM32F4 "
                        "board's crystal: --define GS_HSE_HZ=12000000 (docs/guides/stm32f4.md)")
    b.add_argument("--calibrated", action="store_true",
                   help="servo table with the robot's calibration.toml (a real servo bus: offsets, directions, "
                        "calibrated step ranges)")
    sub.add_parser("targets", help="list the targets: part, flash and RAM budget, build kind, QEMU machine",
                   description="List the targets: part, flash and RAM budget, build kind, QEMU machine.")
    return p


def targets_table() -> str:
    """The :data:`TARGETS` table as text (one header line, one line per target)."""
    rows = [("target", "part", "flash", "RAM", "build kind", "QEMU machine")]
    for t in TARGETS.values():
        rows.append((t.name, t.part, f"{t.flash_bytes // 1024} KB" if t.flash_bytes else "-",
                     f"{t.ram_bytes // 1024} KB" if t.ram_bytes else "-", t.kind, t.qemu_machine or "-"))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows)


def _out_problem(out: Path) -> str | None:
    """Why ``out`` cannot be the folder the files go into, or None."""
    for p in (out, *out.parents):
        if p.exists():
            if not p.is_dir():
                return f"--out {out}: {p} is {'a regular file' if p.is_file() else 'not a folder'}, not a folder"
            if not os.access(p, os.W_OK | os.X_OK):
                return f"--out {out}: {p} is a folder this process cannot write in"
            return None
    return None


def _defines_problem(defines: list[tuple[str, int]], target: Target) -> str | None:
    """Why ``--define`` settings cannot build ``target`` (one line), or None: a name its port does not read, a name
    given twice, a value out of its range (:attr:`Target.defines`)."""
    seen: set[str] = set()
    for name, value in defines:
        spec = target.defines.get(name)
        if spec is None:
            takes = ", ".join(target.defines) or "none"
            return f"--define {name}: target {target.name} reads no such setting (it reads: {takes})"
        if name in seen:
            return f"--define {name}: given twice"
        seen.add(name)
        why = spec.problem(name, value)
        if why is not None:
            return f"--define {why}"
    return None


def _fit_problem(robot_name: str, servo_count: int, target: Target) -> str | None:
    if servo_count > target.max_servos:
        return (f"robot {robot_name} has {servo_count} servos, {target.name} drives at most {target.max_servos}")
    return None


def _budget_problem(robot_name: str, target: Target, flash: int, ram: int) -> str | None:
    """One line when the image is over the target's flash or RAM budget, else None."""
    fb, rb = target.flash_bytes, target.ram_bytes
    over_flash = fb is not None and flash > fb
    over_ram = rb is not None and ram > rb
    if over_flash and over_ram:
        return (f"robot {robot_name} needs {_b(flash)} B flash and {_b(ram)} B RAM, {target.name} has "
                f"{_b(fb or 0)} B flash and {_b(rb or 0)} B RAM")
    if over_ram:
        return (f"robot {robot_name} needs {_b(ram)} B RAM, {target.name} has {_b(rb or 0)} B"
                + (f" (flash {_b(flash)} of {_b(fb)} B)" if fb else ""))
    if over_flash:
        return (f"robot {robot_name} needs {_b(flash)} B flash, {target.name} has {_b(fb or 0)} B"
                + (f" (RAM {_b(ram)} of {_b(rb)} B)" if rb else ""))
    return None


def _write(binary: Path, target: Target, out: Path) -> list[Path]:
    """Copy the build's files into ``out`` (each written beside its final name, then renamed); an ARM
    image's .bin and .hex are the build's (:func:`firmware_sim.cfirmware.build.build` writes them beside the .elf)."""
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    files: list[tuple[str, str | None]] = [(binary.name, None)]
    if target.elf:
        files += [(binary.with_suffix(".bin").name, "binary"), (binary.with_suffix(".hex").name, "ihex")]
    for name, fmt in files:
        src, dest = binary.parent / name, out / name
        fd, tmp_name = tempfile.mkstemp(prefix=f".{name}.", dir=out)
        os.close(fd)
        tmp = Path(tmp_name)
        try:
            shutil.copy2(src, tmp)
            tmp.chmod(0o755 if fmt is None else 0o644)  # the image or executable as the linker made it; data
            os.replace(tmp, dest)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
        written.append(dest)
    return written


def _build(args: argparse.Namespace) -> int:
    from firmware_sim.cfirmware.build import KINDS, BuildError, ToolchainMissing, build
    from robots.datatypes import RobotDataError
    from robots.hardware import CALIBRATION_FILE
    from robots.registry import load_robot

    target = TARGETS[args.target]
    try:
        robot = load_robot(args.robot, args.robots_dir)
    except RobotDataError as e:
        _say(str(e))
        return USAGE
    why = _defines_problem(args.defines, target)
    if why is not None:
        _say(why)
        return USAGE
    if args.calibrated and not (robot.root / CALIBRATION_FILE).is_file():
        _say(f"--calibrated: robot {robot.name} has no {CALIBRATION_FILE} in {robot.root}; measure one first with "
             f"ghostshell robots calibrate {robot.name} --servo-bus PORT (docs/guides/calibration.md)")
        return USAGE
    out: Path = args.out if args.out is not None else Path("firmware") / f"{robot.name}-{target.name}"
    why = _out_problem(out)
    if why is not None:
        _say(why)
        return USAGE
    why = _fit_problem(robot.name, robot.servo_count, target)
    if why is not None:
        _say(why)
        return FAILED
    if target.kind not in KINDS:
        _say(f"target {target.name}: this checkout cannot build it yet (no build kind {target.kind!r} in "
             "firmware_sim/cfirmware/build.py)")
        return FAILED
    settings = "".join(f", {k}={v}" for k, v in args.defines)
    print(f"building {robot.name} ({robot.servo_count} servos) for {target.name}: {target.part}"
          + (", calibrated servo table" if args.calibrated else "") + settings, flush=True)
    try:
        binary = build(target.kind, robot, calibrated=args.calibrated, defines=dict(args.defines) or None)
    except ToolchainMissing as e:
        _say(str(e))
        return FAILED
    except BuildError as e:
        # the port's linker script holds the image to the part's memories: a region overflow is the robot not
        # fitting, one line with its numbers (the compiler's output otherwise)
        need = link_overflow(str(e))
        why = _budget_problem(robot.name, target, *need) if need is not None else None
        _say(why if why is not None else str(e))
        return FAILED
    except RobotDataError as e:  # a bad calibration.toml
        _say(str(e))
        return USAGE
    lines: list[str] = []
    if target.elf:
        try:
            use = image_use(binary)
        except ToolchainMissing as e:
            _say(str(e))
            return FAILED
        why = _budget_problem(robot.name, target, use.flash, use.ram)
        if why is not None:
            _say(why)
            return FAILED
        for what, n, budget in (("flash", use.flash, target.flash_bytes), ("RAM", use.ram, target.ram_bytes)):
            lines.append(f"  {what:<5} {_b(n):>9} B" + (f" of {_b(budget)} B ({_percent(n, budget)})" if budget else ""))
    else:
        lines.append(f"  {target.name}: an executable for this computer, no flash or RAM budget")
    try:
        written = _write(binary, target, out)
    except ToolchainMissing as e:
        _say(str(e))
        return FAILED
    except OSError as e:
        _say(f"cannot write into --out {out}: {e.strerror or e}")
        return USAGE
    lines.append(f"  wrote {out}/: {', '.join(p.name for p in written)}")
    if target.name == "stm32f4":
        lines.append(f"  flash it: st-flash --reset write {out / 'gs_firmware.bin'} 0x08000000 (docs/guides/flashing.md)")
    print("\n".join(lines), flush=True)
    return OK


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``build`` or ``targets`` with ``argv`` (default ``sys.argv[1:]``); returns the exit status."""
    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        args = build_parser().parse_args(argv)
        if args.action == "targets":
            print(targets_table())
            return OK
        return _build(args)
    except KeyboardInterrupt as e:
        _say(f"interrupted by {'SIGTERM' if isinstance(e, _Terminated) else 'SIGINT (Ctrl-C)'}")
        return INTERRUPTED
    except ImportError as e:  # Ctrl-C while an extension module initialises (``import mujoco``: the servo table)
        interrupt = _interrupt_behind(e)
        if interrupt is None:
            raise
        _say(f"interrupted by {'SIGTERM' if isinstance(interrupt, _Terminated) else 'SIGINT (Ctrl-C)'}")
        return INTERRUPTED
    finally:
        signal.signal(signal.SIGTERM, previous)


def _interrupt_behind(error: BaseException) -> KeyboardInterrupt | None:
    """The KeyboardInterrupt an error was raised while handling, if any (as ``host.cli``: a C extension
    whose initialisation a signal cut short reports ``ImportError: initialization failed``)."""
    seen: set[int] = set()
    e: BaseException | None = error
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return e
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return None
