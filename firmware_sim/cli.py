"""``python -m firmware_sim``: the board's command line.

The contract with whatever starts it (the host, :func:`host.link.board_process.start_board`, or a user): a bad
``--link`` or option exits 2 with one line. The first stdout line is ``board: listening on X``: for ``pty`` (and
``can:slcan:pty``) X is the pty the board made and a host connects to ``spec.with_port(X)``; for other links
to the spec as given. It serves until SIGINT/SIGTERM, shuts down cleanly and exits 130; with
``--stop-on-stdin-eof`` it exits 0 when its standard input closes (a board the host started never outlives it).
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
from collections.abc import Sequence
from typing import Any, NoReturn

from protocol.cliargs import push_arg, seed_arg
from protocol.wiremodel import baud_arg
from protocol.linkspec import LinkSpec, LinkSpecError, parse_link_spec
from robots.registry import DEFAULT_ROBOT, robots_dir_arg

__all__ = ["build_parser", "configure", "main"]


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if v <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {v}")
    return v


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not v > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {v}")
    return v


def _link_spec(text: str) -> LinkSpec:
    try:
        return parse_link_spec(text)
    except LinkSpecError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def _servo_bus_spec(text: str) -> tuple[str, int | None]:
    from firmware_sim.servobus import parse_bus_spec

    try:
        return parse_bus_spec(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the board's options to ``parser``."""
    parser.add_argument("--link", required=True, type=_link_spec, metavar="SPEC",
                        help="'pty' creates a pty pair and prints its name; a serial port or pyserial URL; "
                             "or can:INTERFACE:CHANNEL[?node=N&fd=1...] (see docs/concepts/wire.md, Link specs)")
    parser.add_argument("--baud", type=baud_arg, default=None,
                        help="model wire time at this baud rate (10 bits/byte, both directions)")
    parser.add_argument("--rate", type=_positive_int, default=500, metavar="HZ", help="control loop rate (default 500)")
    parser.add_argument("--dt", type=_positive_float, default=0.002, metavar="S", help="physics step (default 0.002)")
    clock = parser.add_mutually_exclusive_group()
    clock.add_argument("--realtime", dest="lockstep", action="store_false",
                       help="pace to the wall clock (default)")
    clock.add_argument("--lockstep", dest="lockstep", action="store_true",
                       help="virtual time: advance only as far as the host's frames or ADVANCE (for tests and "
                            "replays; which mode a host should use: the wire protocol page below)")
    parser.set_defaults(lockstep=False)
    parser.add_argument("--telemetry-rate", type=_positive_int, default=50, metavar="HZ",
                        help="TELEMETRY and SIM_STATE rate (default 50)")
    parser.add_argument("--watchdog-ms", type=_positive_int, default=200, metavar="MS",
                        help="link silence before holding position (default 200)")
    parser.add_argument("--log", default=None, metavar="FILE", help="write every frame in/out as JSON lines")
    parser.add_argument("--objects-log", default=None, metavar="FILE",
                        help="write the scene's movable objects' poses with every SIM_STATE as JSON lines "
                             "(simulation ground truth for the video; see docs/guides/robots.md; the Python board only: "
                             "ignored with --firmware c|qemu|stm32f4)")
    parser.add_argument("--faults", default=None, metavar="SPEC",
                        help="inject link faults both ways (serial and CAN), e.g. drop=0.01,corrupt=0.01,dup=0.005,"
                             "reorder=0.005,truncate=P,delay=MS[±MS],cut=START+LEN (see docs/guides/faults.md)")
    parser.add_argument("--fault-seed", type=seed_arg, default=0, metavar="N", help="seed of the fault injectors (default 0)")
    parser.add_argument("--viewer", action="store_true", help="open MuJoCo's viewer (needs a display)")
    parser.add_argument("--robot", default=DEFAULT_ROBOT, metavar="NAME",
                        help=f"the robot this board drives: a name (ghostshell robots list) or a robot folder "
                             f"(default {DEFAULT_ROBOT})")
    parser.add_argument("--robots-dir", default=None, metavar="DIR", type=robots_dir_arg, help="search this folder for --robot first")
    parser.add_argument("--push", action="append", default=[], type=push_arg, metavar="S:FX,FY,FZ[:DUR]",
                        help="emulator only: push the robot's base with a force (N, world frame) at board time S "
                             "for DUR s (default 0.2); repeatable (a scripted disturbance, e.g. to test falls)")
    parser.add_argument("--scene", default=None, metavar="NAME",
                        help="objects in the world: one of the robot's scenes (default: the robot's default scene)")
    parser.add_argument("--stop-on-stdin-eof", action="store_true",
                        help="stop when standard input closes: a host that starts the board gives it a pipe, so the "
                             "board never outlives that host, however the host ends")

    parser.add_argument("--firmware", choices=FIRMWARES, default="python",
                        help="python: this emulator (default); c: the C firmware built natively, its servos on a "
                             "Feetech bus to the MuJoCo plant; qemu: the same C firmware as a Cortex-M3 image on "
                             "qemu-system-arm -M mps2-an385; stm32f4: its STM32F405 image (the one real boards run) "
                             "on qemu-system-arm -M netduinoplus2")
    parser.add_argument("--dead-servo", action="append", default=[], type=_dead_servo, metavar="ID@SECONDS",
                        help="--firmware c|qemu|stm32f4: servo ID stops answering on the bus at world time SECONDS (a fault)")
    parser.add_argument("--icount", action="store_true",
                        help="--firmware qemu|stm32f4: -icount shift=0 (one instruction per virtual ns; tick cost figures; "
                             "stm32f4: every tick's cost, median/p99/max at exit)")
    parser.add_argument("--asan", action="store_true",
                        help="--firmware c: run the AddressSanitizer/UBSan build of the firmware")
    parser.add_argument("--servo-bus", type=_servo_bus_spec, default=None, metavar="PORT[:BAUD]",
                        help="drive the robot's REAL servos on this serial port (a USB adapter, e.g. /dev/ttyUSB0) "
                             "instead of simulating them; MuJoCo mirrors what they measure. BAUD: default the robot's "
                             "hardware.toml (see docs/guides/hardware.md)")
    parser.add_argument("--bus-protocol", choices=BUS_PROTOCOL_CHOICES, default=None,
                        help="--servo-bus: sts (Feetech SCS/STS) or dxl2 (Dynamixel Protocol 2.0); default the "
                             "robot's hardware.toml, else sts")
    parser.add_argument("--estop-torque", choices=("hold", "limp"), default=None,
                        help="--servo-bus: what ESTOP does to the servos: hold (default: torque on, hold position) "
                             "or limp (torque off; back on at ESTOP_CLEAR from where they are)")


FIRMWARES = ("python", "c", "qemu", "stm32f4")
#: the firmwares that are a QEMU guest (firmware_sim.cfirmware.launcher.QEMU_MACHINES): --icount applies
QEMU_FIRMWARES = ("qemu", "stm32f4")
BUS_PROTOCOL_CHOICES = ("sts", "dxl2")
#: a lockstep board waits this long (ms, beyond the wire time) for a servo's answer: its time is virtual,
#: so a long wait costs nothing but a dead servo's detection; realtime uses the SDKs' LATENCY_TIMER (16 ms)
LOCKSTEP_BUS_LATENCY_MS = 100.0
REALTIME_BUS_LATENCY_MS = 16.0

#: The name the usage line shows: ``ghostshell board`` sets it when it runs the board for the user.
PROG_ENV = "GHOSTSHELL_BOARD_PROG"


def _dead_servo(text: str) -> tuple[int, float]:
    sid, sep, at = text.partition("@")
    try:
        v = (int(sid), float(at or "0"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected ID@SECONDS (e.g. 3@2.5), got {text!r}") from None
    if not 1 <= v[0] <= 253 or v[1] < 0:
        raise argparse.ArgumentTypeError(f"servo id must be 1..253 and the time >= 0, got {text!r}")
    return v


class _OneLineParser(argparse.ArgumentParser):
    """A usage error is one line, ``PROG: error: WHY (PROG --help: usage)``, exit status 2, without
    argparse's usage block before it (as ``host.cli.OneLineParser``; the board imports nothing of the host)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} ({self.prog} --help: usage)\n")


def build_parser() -> argparse.ArgumentParser:
    p = _OneLineParser(prog=os.environ.get(PROG_ENV) or "python -m firmware_sim",
                                description="A robot's emulated board (MuJoCo).",
                                epilog="The wire protocol a host speaks to this board (messages, refusals,\n"
                                       "realtime or lockstep, start-up): docs/wire-protocol.md",
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    configure(p)
    return p


#: exit status of a board a signal stopped (SIGINT, SIGTERM), after its clean shutdown: the CLI's
#: exit status table's "interrupted" (128 + SIGINT, as a shell reports Ctrl-C)
INTERRUPTED_STATUS = 130
#: set when standard input closed (``--stop-on-stdin-eof``): that stop is the owner's normal end, exit 0
_STDIN_CLOSED = threading.Event()


def _stop_on_stdin_eof() -> None:
    """Read standard input until it closes, then stop the board as SIGTERM does (in a daemon thread);
    the board then exits 0, not :data:`INTERRUPTED_STATUS` (closing stdin is how its owner ends it)."""

    def watch() -> None:  # os.read on the fd: a thread blocked in sys.stdin would hold its lock at exit
        try:
            while os.read(0, 4096):
                pass
        except OSError:
            pass
        _STDIN_CLOSED.set()
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=watch, name="stdin-eof", daemon=True).start()


def _run_c_firmware(args: argparse.Namespace, robot: object, parser: argparse.ArgumentParser) -> int:
    """``--firmware c|qemu|stm32f4``: the C firmware with the servo-bus plant (firmware_sim.cfirmware.launcher)."""
    from firmware_sim.cfirmware.launcher import LaunchOptions, run_firmware
    from firmware_sim.config import BoardConfig, ConfigError

    try:
        BoardConfig(rate_hz=args.rate, dt=args.dt, telemetry_rate_hz=args.telemetry_rate,
                    watchdog_ms=args.watchdog_ms).validate()
    except ConfigError as e:
        parser.error(str(e))
    if args.viewer:
        parser.error("--viewer is not available with --firmware c|qemu|stm32f4")
    if args.icount and args.firmware not in QEMU_FIRMWARES or args.asan and args.firmware != "c":
        parser.error("--icount needs --firmware qemu or stm32f4; --asan needs --firmware c")
    fault_spec = None
    if args.faults:
        from protocol.faults import FaultSpec, FaultSpecError

        try:
            fault_spec = FaultSpec.parse(args.faults)
        except FaultSpecError as e:
            parser.error(f"--faults: {e}")
    if args.servo_bus is not None and args.dead_servo:
        parser.error("--dead-servo is a fault of the emulated bus; it has no meaning with --servo-bus")
    # the bus the firmware speaks: the real one (--servo-bus), else the plant's emulated servos, in the robot's
    # protocol (hardware.toml) or --bus-protocol's
    hw = _bus_hardware(args, robot)
    if hw is None:
        return 2
    bus: dict[str, object] = {"bus_protocol": hw.protocol, "estop_torque": args.estop_torque or "hold"}
    if args.servo_bus is not None:
        bus |= {"servo_bus_port": args.servo_bus[0], "servo_bus_baud": args.servo_bus[1] or hw.baud}
    opts = LaunchOptions(robot=robot, firmware=args.firmware, link=args.link, lockstep=args.lockstep,  # type: ignore[arg-type]
                         rate_hz=args.rate, dt=args.dt, telemetry_rate_hz=args.telemetry_rate,
                         watchdog_ms=args.watchdog_ms, scene=args.scene, baud=args.baud, log_path=args.log,
                         faults=fault_spec, fault_seed=args.fault_seed, dead_servos=list(args.dead_servo),
                         asan=args.asan, icount=args.icount, **bus)  # type: ignore[arg-type]
    return run_firmware(opts)


def _bus_hardware(args: argparse.Namespace, robot: Any, who: str = "board: ") -> Any:
    """The robot's ``hardware.toml`` with ``--bus-protocol`` applied (:class:`robots.hardware.Hardware`),
    or None after printing the one line why not (a bad file, a protocol that contradicts it), after ``who``."""
    from robots.datatypes import RobotDataError
    from robots.hardware import DEFAULT_BAUD, DEFAULT_MODEL, HARDWARE_FILE, Hardware, load_hardware

    try:
        hw = load_hardware(robot.root, list(robot.servos))
    except RobotDataError as e:
        print(f"{who}{e}", file=sys.stderr)
        return None
    has_file = (robot.root / HARDWARE_FILE).is_file()
    want = args.bus_protocol
    if want is not None and want != hw.protocol:
        if has_file:
            print(f"{who}--bus-protocol {want} contradicts {robot.root / HARDWARE_FILE} (protocol = "
                  f"{hw.protocol!r}); fix the file or leave --bus-protocol out", file=sys.stderr)
            return None
        hw = Hardware(want, DEFAULT_BAUD[want], DEFAULT_MODEL[want])
    return hw


def _start_bus(args: argparse.Namespace, robot: Any, board: Any) -> Any:
    """Open ``--servo-bus``, check every servo, read where they are and attach the bus to ``board``
    (:class:`firmware_sim.servobus.driver.BusDriver`, torque still off), or None after printing the
    one line why not (the port, the baud, a servo missing, twice, garbled or of the wrong model)."""
    from firmware_sim.servobus import BusError, make_bus
    from firmware_sim.servobus.driver import BusDriver
    from robots.datatypes import RobotDataError
    from robots.hardware import load_calibration

    port, baud = args.servo_bus
    # every refusal reads "board: servo bus PORT: why": the host's board launcher (host.link.board_process)
    # then says the board cannot use its servo bus, not that it cannot serve its link
    who = f"board: servo bus {port}: "
    hw = _bus_hardware(args, robot, who)
    if hw is None:
        return None
    latency = LOCKSTEP_BUS_LATENCY_MS if args.lockstep else REALTIME_BUS_LATENCY_MS
    try:
        cal = load_calibration(robot.root, list(robot.servos))
        driver = BusDriver(make_bus(hw.protocol, port, baud or hw.baud, latency_ms=latency), robot, hw, cal,
                           estop_torque=args.estop_torque or "hold")
    except RobotDataError as e:
        print(f"{who}{e}", file=sys.stderr)
        return None
    try:
        positions = driver.start()
    except BusError as e:
        driver.close()
        print(f"{who}{e}", file=sys.stderr)
        return None
    except BaseException:
        driver.close()
        raise
    print(f"board: {driver.plan(board.tick_us / 1e6, lockstep=args.lockstep)}", file=sys.stderr, flush=True)
    board.attach_bus(driver, positions)
    return driver


class _Stop(BaseException):  # not Exception: a handler that guards against bugs must not swallow it
    pass


def _raise_stop(signum: int, frame: object) -> None:
    raise _Stop()


def main(argv: Sequence[str] | None = None) -> int:
    """Run the board until SIGINT/SIGTERM; 0 (stdin closed with ``--stop-on-stdin-eof``), 130 (stopped
    by a signal, after a clean shutdown), 1 (the C firmware died) or 2 (bad arguments or link)."""
    try:
        status = _main(argv)
    except KeyboardInterrupt:  # Ctrl-C while loading, before the handlers: nothing was serving yet
        print("board: interrupted while starting", file=sys.stderr, flush=True)
        return INTERRUPTED_STATUS
    if status == INTERRUPTED_STATUS and _STDIN_CLOSED.is_set():
        return 0
    return status


def _main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    has_display = bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    if args.viewer and not has_display:
        parser.error("--viewer needs a display (DISPLAY/WAYLAND_DISPLAY is not set); run without --viewer")
    if not has_display:
        os.environ.setdefault("MUJOCO_GL", "egl")  # offscreen camera rendering must not need X

    from firmware_sim.board import Board
    from firmware_sim.config import BoardConfig, ConfigError
    from firmware_sim.gc_freeze import freeze_heap
    from firmware_sim.server import BoardServer
    from firmware_sim.transports import open_board_transport
    from protocol.linkkinds import link_kind
    from robots.description import RobotDataError
    from robots.registry import load_robot

    try:
        robot = load_robot(args.robot, args.robots_dir)
    except RobotDataError as e:
        print(f"board: {e}", file=sys.stderr)
        return 2
    if args.scene is not None and args.scene not in robot.scenes:
        print(f"board: {robot.name} has no scene {args.scene!r}; scenes: {', '.join(robot.scenes)}", file=sys.stderr)
        return 2
    if args.firmware != "python":
        if args.stop_on_stdin_eof:  # the launcher stops on SIGTERM, as the Python board does
            _stop_on_stdin_eof()
        return _run_c_firmware(args, robot, parser)
    if args.dead_servo or args.icount or args.asan:
        parser.error("--dead-servo, --icount and --asan need --firmware c, qemu or stm32f4")
    if args.servo_bus is None and (args.bus_protocol is not None or args.estop_torque is not None):
        parser.error("--bus-protocol and --estop-torque need --servo-bus PORT")
    if args.servo_bus is not None and args.push:
        parser.error("--push pushes a simulated robot; with --servo-bus the robot is real")
    cfg = BoardConfig(
        rate_hz=args.rate, dt=args.dt, lockstep=args.lockstep,
        telemetry_rate_hz=args.telemetry_rate, watchdog_ms=args.watchdog_ms, robot=args.robot,
        robots_dir=args.robots_dir, scene=args.scene,
        kernel="python" if args.servo_bus is not None else None,  # the native tick steps physics
    )
    try:
        cfg.validate()
    except ConfigError as e:
        parser.error(str(e))
    kind = link_kind(args.link)
    if args.baud is not None and not kind.models_baud:
        parser.error(f"--baud: the board does not model a serial line's rate on {args.link} (a CAN link: its "
                     f"rate is the bus's, ?bitrate=); leave --baud out, or use --link pty")
    if not kind.cross_process:
        print(f"board: {args.link} is python-can's in-process virtual bus: a board process serving it could "
              "never be reached by a host in another process; use can:slcan:pty or can:socketcan:vcan0 "
              "(tests serve the virtual bus in-process with firmware_sim.transports.open_board_transport)",
              file=sys.stderr)
        return 2
    try:
        link = open_board_transport(args.link, baud=args.baud, log_path=args.log, servo_count=robot.servo_count)
    except Exception as e:
        if kind.wire == "can":
            from protocol.can.bus_errors import describe_bus_open_error

            print(f"board: {describe_bus_open_error(args.link, e)}", file=sys.stderr)
        else:
            print(f"board: cannot open link {str(args.link)!r}: {e}", file=sys.stderr)
        return 2
    fault_spec = None
    if args.faults:
        from protocol.faults import FaultSpec, FaultSpecError

        try:
            fault_spec = FaultSpec.parse(args.faults)
        except FaultSpecError as e:
            link.close()
            parser.error(f"--faults: {e}")
    injectors = []
    if fault_spec is not None and fault_spec.active:
        from firmware_sim.transports.faulty import install_faults

        try:
            injectors = install_faults(link, fault_spec, args.fault_seed)
        except ValueError as e:
            link.close()
            print(f"board: {e}", file=sys.stderr)
            return 2
    board = Board(cfg, robot=robot)
    for at, force, dur in args.push:
        board.push(at, force, dur)
    driver = None
    if args.servo_bus is not None:
        driver = _start_bus(args, robot, board)
        if driver is None:
            link.close()
            return 2
    # Realtime renders in a thread, its GL context made (and checked) before the link comes up: the first
    # capture would otherwise stall the control loop. Lockstep renders in the loop (deterministic) and
    # makes the renderer at the first capture: virtual time waits for it, and most runs never capture,
    # so no lockstep boot pays the GL setup and first render (0.7 -> 0.45 s per boot; a capture that
    # cannot render is refused with the reason then, NO_RENDERER).
    why = None
    if robot.peripherals.camera is not None and not cfg.lockstep:
        why = board.start_camera_worker()
    if why is not None:
        print(f"board: camera captures will be refused: {why}", file=sys.stderr)
    viewer = None
    if args.viewer:
        import mujoco.viewer

        try:
            viewer = mujoco.viewer.launch_passive(board.model, board.data)
        except Exception as e:
            link.close()
            print(f"board: cannot open the viewer: {e}", file=sys.stderr)
            return 2
    objects_log = None
    if args.objects_log:
        from firmware_sim.objects_log import ObjectsLog

        try:
            objects_log = ObjectsLog(args.objects_log, board)
        except OSError as e:
            link.close()
            print(f"board: cannot write --objects-log {args.objects_log}: {e}", file=sys.stderr)
            return 2
    server = BoardServer(board, link, viewer=viewer, objects_log=objects_log)
    status = 0
    try:  # from the handlers on: a signal at any point after them ends in the clean shutdown below
        signal.signal(signal.SIGTERM, _raise_stop)
        signal.signal(signal.SIGINT, _raise_stop)
        if args.stop_on_stdin_eof:
            _stop_on_stdin_eof()
        freeze_heap()  # full GC passes over the loaded model would stall ticks for tens of ms (firmware_sim.gc_freeze)
        print(f"board: listening on {link.name}", flush=True)
        mode = "lockstep" if cfg.lockstep else "realtime"
        print(f"board: {robot.name} ({robot.servo_count} servos), {mode}, {cfg.rate_hz} Hz, dt {cfg.dt} s, "
              f"telemetry {cfg.telemetry_rate_hz} Hz"
              + (f", {args.baud} baud" if args.baud else ""), file=sys.stderr, flush=True)
        if not cfg.lockstep:  # a realtime board's ticks must not wait for other work (firmware_sim.priority)
            from firmware_sim.priority import raise_priority, tighten_timer_slack

            print(f"board: {raise_priority()}; {tighten_timer_slack()}", file=sys.stderr, flush=True)
        if args.baud:
            from protocol.framing import frame_size

            need = cfg.telemetry_rate_hz * (frame_size(board.telemetry(), board.wire_schema)
                                            + frame_size(board.sim_state(), board.wire_schema)) * 10
            if need > 0.8 * args.baud and cfg.lockstep:  # it waits for the line (firmware_sim.server)
                print(f"board: warning: telemetry needs ~{need} bit/s of board time, more than 80% of {args.baud} baud; "
                      f"this lockstep board keeps every report and runs no faster than the line carries them "
                      f"(~{args.baud / need:.2g}x real time)", file=sys.stderr, flush=True)
            elif need > 0.8 * args.baud:
                # each period's TELEMETRY goes first, and a report that finds the line still busy is dropped
                # (firmware_sim.server): the SIM_STATE behind it goes first (at 57 600 baud every one of them)
                print(f"board: warning: telemetry needs ~{need} bit/s, more than 80% of {args.baud} baud; reports "
                      "will be dropped, SIM_STATE (the base pose and tilt) first, up to all of them (raise --baud, "
                      "or lower the board's --telemetry-rate)", file=sys.stderr, flush=True)
        if driver is not None:
            driver.torque_on()  # only now: the board's command starts at the measured positions
            indirect = getattr(driver.bus, "indirect", None)  # Dynamixel only
            how = "" if indirect is None else (", one sync read through indirect addresses" if indirect
                                               else ", one sync read + the hardware error status on an alert")
            print(f"board: servo bus {driver.bus.port} ({driver.bus.protocol}, {driver.bus.baud} baud{how}): "
                  f"{driver.n} servos answer, torque on; ESTOP {driver.estop_torque}s", file=sys.stderr, flush=True)
        server.serve()
    except (_Stop, KeyboardInterrupt):
        status = INTERRUPTED_STATUS
    finally:
        if driver is not None:  # torque off on the whole bus, on every way out; a second Ctrl-C must not cut it short
            signal.signal(signal.SIGTERM, signal.SIG_IGN)
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            driver.close()
            c = driver.bus.counts
            print(f"board: servo bus torque off; {c['sync_writes']} goal writes, {c['sync_reads']} reads, "
                  f"{c['timeouts']} timeouts, {c['corrupt']} garbled answers", file=sys.stderr, flush=True)
            import json

            # the host's runner copies this line into summary.json (extra.servo_bus), as it does board: faults
            print(f"board: servo bus {json.dumps(driver.summary(), separators=(',', ':'))}", file=sys.stderr,
                  flush=True)
        if injectors and fault_spec is not None:
            from firmware_sim.transports.faulty import report_line

            print(report_line(fault_spec, args.fault_seed, injectors, board), file=sys.stderr, flush=True)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        if server.clock is not None:
            print(f"board: {server.clock.stats.summary()}", file=sys.stderr, flush=True)
        if server.tx_dropped:
            print(f"board: {server.tx_dropped} outgoing report(s) dropped (link too slow)", file=sys.stderr, flush=True)
        if server.tx_dropped_no_host:
            print(f"board: {server.tx_dropped_no_host} report(s) not sent while no host was talking to the board "
                  "(nothing read the link; not a fault)", file=sys.stderr, flush=True)
        note = link.exit_note()
        if note:
            print(f"board: {note}", file=sys.stderr, flush=True)
        if viewer is not None:
            viewer.close()
        if objects_log is not None:
            objects_log.close()
        link.close()
    return status
