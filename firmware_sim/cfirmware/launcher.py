"""Run the C firmware as the board: ``python -m firmware_sim --firmware c|qemu|stm32f4 --link pty ...``.

One process (this one) holds the world; the firmware runs as its own process:

* ``c``: the native build (:mod:`firmware_sim.cfirmware.build`, kind ``native``) as a subprocess:
  ``gs_firmware --bus fd:N --host pty`` (it creates the host pty itself, as a board's UART; the servo
  bus is one end of a socketpair, :class:`_SocketBus`);
* ``qemu``: the Cortex-M3 image on ``qemu-system-arm -M mps2-an385``: UART0 = a socketpair end this
  process relays byte for byte to the host's pty (QEMU's own ``-serial pty`` notices its peer by polling
  once a second, which would hold the host's first bytes back; a socket has no tty layer), UART1 = the servo bus (a socketpair
  end, ``-chardev socket,id=bus,fd=N``), UART2 =
  ``-serial stdio`` (the log channel); boot settings go into the image's configuration block through
  QEMU's generic loader. ``icount=True`` adds ``-icount shift=0,sleep=on`` (one instruction per
  virtual nanosecond: the tick-cost figure);
* ``stm32f4``: the STM32F405/F407 image (``ports/stm32f4``) on ``qemu-system-arm -M netduinoplus2``, wired
  the same way: USART2 = the host (relayed), USART6 = the servo bus, USART3 = the log channel
  (:data:`QEMU_MACHINES` holds each machine's serial order and boot-block address). With ``icount`` it runs
  the trace build, whose every tick's cost ends the run as ``board: tick cost per tick (cycles): median
  ..., p99 ..., max ..., n ...``.

Realtime, this process first raises its priority as the Python board does (:mod:`firmware_sim.priority`:
nice -10 where permitted, 1 ns timer slack); the firmware it starts inherits both.

This process is the servo-bus plant (:mod:`firmware_sim.plant`: the robot's MuJoCo model behind
Feetech SCS/STS devices on a pty) and reads the firmware's log channel: ``board: ...`` lines go to
stderr as the Python board prints them, ``F rx|tx T HEX`` records become the JSON-Lines frame log
(``--log``; decoded here with :mod:`protocol.framelog`, the raw bytes are the firmware's),
``S key=value`` records are its counters (the ``board: faults {json}`` line at exit; in realtime also
``board: realtime lateness {json}``, :func:`lateness_record`: how far the firmware and the plant fell
behind the wall clock, told as lateness rather than as a dead servo).

The host link is the firmware's own UART pty (native), except with ``--faults`` or ``--baud``: then the
line between host and firmware is modelled here (the Python board's
:class:`protocol.wiremodel.WireModel` and :class:`firmware_sim.transports.faulty.FaultyWire`
between two ptys), so the faults hit the firmware's UART as bytes on a bad wire would.

SIM_STATE: the firmware forwards what the emulator-only probe device on its bus reports (ground
truth the plant knows and no real robot has; on hardware nothing answers and no SIM_STATE is sent).

The servo bus: ``bus_protocol`` "sts" (Feetech) or "dxl2" (Dynamixel Protocol 2.0) is the firmware's
(``--protocol``; QEMU: its configuration block) and the in-process plant's. ``servo_bus_port`` (native
only) is a real bus: the firmware opens that tty itself (``--bus tty:PORT:BAUD``, raw 8N1; baud
``servo_bus_baud``, default the protocol's 1 Mbaud) and no plant runs here (no world, no SIM_STATE).
With a real bus the firmware is built with the robot's ``calibration.toml`` in its servo table
(:func:`firmware_sim.cfirmware.build.build` ``calibrated=True``: offsets, directions, calibrated step ranges).
``estop_torque``: "hold" (ESTOP holds where the servos are) or "limp" (torque off until ESTOP_CLEAR).
A stopped firmware turns every servo's torque off.
"""

from __future__ import annotations

import json
import os
import re
import select
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from firmware_sim.cfirmware.build import BuildError, build, require
from firmware_sim.cfirmware.targets import link_overflow
from firmware_sim.plant.bus import PlantBus
from firmware_sim.plant.world import World
from firmware_sim.transports.ports import PtyPort
from protocol.can.frame import CanFrame
from protocol.codec import WireSchema, schema_for
from protocol.faults import FaultInjector, FaultSpec
from protocol.framing import FRAME_DELIMITER
from protocol.linkkinds import link_kind
from protocol.linkspec import LinkSpec
from protocol.logfile import FrameLogWriter, open_frame_log
from protocol.wiremodel import WireModel
from robots.datatypes import RobotDataError
from robots.description import Robot

__all__ = ["LATENESS_PREFIX", "LaunchOptions", "lateness_record", "lateness_warning", "run_firmware"]

BOOT_MAGIC = 0x47534346


@dataclass(frozen=True)
class QemuMachine:
    """A QEMU board the C firmware runs on as an MCU image (``--firmware`` value -> :data:`QEMU_MACHINES`).

    ``serials``: what each ``-serial`` argument carries, in QEMU's order for the machine (``host``, ``bus``,
    ``log`` or ``null``); ``boot_cfg_addr``: the image's configuration block (its linker script puts
    ``.bootcfg`` first in RAM); ``clock_hz``: the core clock its SysTick counts (the tick-cost figure);
    ``trace_kind``: the build that logs every tick's cost, used with ``icount``."""

    machine: str
    kind: str
    serials: tuple[str, ...]
    boot_cfg_addr: int
    clock_hz: int
    trace_kind: str | None = None


#: ``qemu``: the Cortex-M3 image on mps2-an385 (CMSDK UART0..2 = host, bus, log); ``stm32f4``: the STM32F405
#: image on netduinoplus2, whose -serial arguments are USART1, USART2, USART3, UART4, UART5, USART6 in that
#: order (hw/arm/stm32f405_soc.c): USART2 host, USART3 log, USART6 the servo bus (ports/stm32f4/hal_stm32f4.c)
QEMU_MACHINES: dict[str, QemuMachine] = {
    "qemu": QemuMachine("mps2-an385", "mps2", ("host", "bus", "log"), 0x20000000, 25_000_000),
    "stm32f4": QemuMachine("netduinoplus2", "stm32f4", ("null", "host", "log", "null", "null", "bus"), 0x20000000,
                           168_000_000, trace_kind="stm32f4-trace"),
}
_CHARDEV = re.compile(r"char device redirected to (\S+) \(label (\w+)\)")
STATS_KEYS = ("link_errors", "late_frames", "dropped_frames", "watchdog_trips", "seq_gaps")


@dataclass
class LaunchOptions:
    robot: Robot
    firmware: str = "c"  # "c" (native), or a QEMU image: "qemu" (mps2-an385), "stm32f4" (netduinoplus2)
    link: LinkSpec | None = None
    lockstep: bool = False
    rate_hz: int = 500
    dt: float = 0.002
    telemetry_rate_hz: int = 50
    watchdog_ms: int = 200
    scene: str | None = None
    baud: int | None = None
    log_path: str | None = None
    faults: FaultSpec | None = None
    fault_seed: int = 0
    dead_servos: list[tuple[int, float]] = field(default_factory=list)  # (servo id, world seconds)
    asan: bool = False  # native: the ASan/UBSan build
    icount: bool = False  # qemu, stm32f4: -icount shift=0
    servo_bus_port: str | None = None  # native: a real servo bus (tty path); no plant runs
    servo_bus_baud: int | None = None  # its baud (None: the protocol's default, 1 Mbaud)
    bus_protocol: str = "sts"  # "sts" (Feetech SCS/STS) or "dxl2" (Dynamixel Protocol 2.0)
    estop_torque: str = "hold"  # ESTOP: "hold" (torque on, where the servos are) or "limp" (torque off)


#: exit status of a board a signal stopped (SIGINT, SIGTERM): the CLI's "interrupted", 128 + SIGINT
INTERRUPTED_STATUS = 130
#: seconds the launcher waits for the firmware (or QEMU) to exit on SIGTERM before it kills it. Kept well
#: under the host's own budget for stopping the launcher (``host.link.board_process.BoardProcess.stop``,
#: 10 s, then SIGKILL), so the launcher always has time left to drain the firmware's last log lines and end
#: a realtime run's stderr with its lateness record (a CI run at load ~4: QEMU slow to exit, the launcher
#: killed mid-wait, no record; tests/cfirmware/test_stop_budget.py keeps the margin)
FIRMWARE_STOP_S = 2.0


class _Stop(BaseException):
    pass


def _raise_stop(signum: int, frame: object) -> None:
    raise _Stop()


class _SocketBus:
    """The servo bus to the native firmware as a UNIX socketpair (the firmware gets ``--bus fd:N``).

    A pty moves bytes between its ends through a kernel worker thread at normal priority, and a read of an
    empty tty waits for that worker: with a CPU hog on every core the native firmware sat in that wait
    (``__flush_work``) for 100 ms and more and skipped ticks. A socketpair has no such worker. Same
    interface as :class:`PtyPort` for the launcher's loop (``master``, ``name``, ``read``, ``write``,
    ``close``) plus ``pass_fds``/``started`` for the child's end."""

    def __init__(self) -> None:
        import socket

        self._ours, self._theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
        self._ours.setblocking(False)
        self.master = self._ours.fileno()
        self.name = f"fd:{self._theirs.fileno()}"
        self.pass_fds: tuple[int, ...] = (self._theirs.fileno(),)

    def started(self) -> None:
        """The child holds its end now: close ours of it."""
        self._theirs.close()

    def read(self) -> bytes:
        try:
            return self._ours.recv(65536)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError:
            return b""

    def write(self, data: bytes) -> int:
        try:
            return self._ours.send(data)
        except (BlockingIOError, InterruptedError):
            return 0
        except OSError:  # the firmware is gone: its exit is noticed by the loop
            return len(data)

    def close(self) -> None:
        self._ours.close()
        self._theirs.close()


#: the firmware's servo-bus protocols (gs_bus.h: GS_BUS_STS 0, GS_BUS_DXL2 1) and ESTOP torque settings
BUS_PROTOCOLS = {"sts": 0, "dxl2": 1}
ESTOP_TORQUE = {"hold": 0, "limp": 1}
DEFAULT_SERVO_BAUD = 1_000_000


def _boot_checks(opts: LaunchOptions) -> bool:
    """Whether the firmware refuses to start on a failed boot check (gs_board_boot). Not with the emulator's
    injected dead servo (``--dead-servo ID@0`` may be dead at boot): a fault found mid-run, as the Python board's
    emulated bus has it."""
    return not (opts.dead_servos and opts.servo_bus_port is None)


def boot_config_words(opts: LaunchOptions) -> list[int]:
    """The configuration block the MCU image reads at boot (magic, settings, check word)."""
    words = [BOOT_MAGIC, int(opts.lockstep), opts.rate_hz, opts.telemetry_rate_hz, opts.watchdog_ms,
             int(bool(opts.log_path)), BUS_PROTOCOLS[opts.bus_protocol], ESTOP_TORQUE[opts.estop_torque],
             int(_boot_checks(opts))]
    check = 0
    for w in words:
        check ^= w
    return [*words, check]


def firmware_command(opts: LaunchOptions, exe: Path, bus_tty: str, host: str) -> list[str]:
    """The command line that starts the firmware with its UARTs on ``host`` and ``bus_tty``."""
    if opts.firmware == "c":
        cmd = [str(exe), "--bus", bus_tty, "--host", host, "--lockstep" if opts.lockstep else "--realtime",
               "--rate", str(opts.rate_hz), "--telemetry-rate", str(opts.telemetry_rate_hz),
               "--watchdog-ms", str(opts.watchdog_ms), "--protocol", opts.bus_protocol,
               "--estop-torque", opts.estop_torque]
        cmd += [] if _boot_checks(opts) else ["--no-boot-checks"]
        return cmd + (["--log-frames"] if opts.log_path else [])
    m = QEMU_MACHINES[opts.firmware]
    # a socket descriptor QEMU inherits ("fd:N", no tty layer: _SocketBus) is a socket chardev
    chardevs = {name: path[3:] for name, path in (("host", host), ("bus", bus_tty)) if path.startswith("fd:")}
    serial = {name: f"chardev:{name}" if name in chardevs else path for name, path in (("host", host), ("bus", bus_tty))}
    serial |= {"log": "stdio", "null": "null"}
    cmd = [require("qemu-system-arm"), "-M", m.machine, "-display", "none", "-monitor", "none", "-kernel", str(exe)]
    for role in m.serials:
        cmd += ["-serial", serial[role]]
    for name, fd in chardevs.items():
        cmd += ["-chardev", f"socket,id={name},fd={fd}"]
    for k, w in enumerate(boot_config_words(opts)):
        cmd += ["-device", f"loader,addr={m.boot_cfg_addr + 4 * k:#x},data={w:#x},data-len=4"]
    if opts.icount:
        cmd += ["-icount", "shift=0,sleep=on"]
    return cmd


class _Relay:
    """The modelled line between the host's pty and the firmware's (wire time and/or faults)."""

    def __init__(self, baud: int | None, faults: FaultSpec | None, seed: int, *, fw_socket: bool = False) -> None:
        from firmware_sim.transports.faulty import FaultyWire

        self.host = PtyPort()  # the host connects to host.name
        # the firmware's UART opens fw.name (QEMU: a socketpair end it inherits, ``fd:N``: no tty layer)
        self.fw: PtyPort | _SocketBus = _SocketBus() if fw_socket else PtyPort()
        # released frame by frame, as a UART delivers: one read may hold several
        self.to_fw: Any = WireModel(baud, FRAME_DELIMITER)
        self.to_host: Any = WireModel(baud, FRAME_DELIMITER)
        self.injectors: list[FaultInjector[bytes]] = []
        if faults is not None and faults.active:
            rx: FaultInjector[bytes] = FaultInjector(faults, seed, "host->board")
            tx: FaultInjector[bytes] = FaultInjector(faults, seed, "board->host")
            self.to_fw, self.to_host = FaultyWire(self.to_fw, rx), FaultyWire(self.to_host, tx)
            self.injectors = [rx, tx]
        self.pend_fw = bytearray()
        self.pend_host = bytearray()

    def fds(self) -> list[int]:
        return [self.host.master, self.fw.master]

    def on_readable(self, fd: int, now: float) -> None:
        if fd == self.host.master:
            data = self.host.read()
            if data:
                self.to_fw.push(now, data)
        elif fd == self.fw.master:
            data = self.fw.read()
            if data:
                self.to_host.push(now, data)

    def pump(self, now: float) -> None:
        self.pend_fw += self.to_fw.pop_ready(now)
        self.pend_host += self.to_host.pop_ready(now)
        if self.pend_fw:
            del self.pend_fw[: self.fw.write(bytes(self.pend_fw))]
        if self.pend_host:
            del self.pend_host[: self.host.write(bytes(self.pend_host))]

    def next_time(self) -> float | None:
        times = [t for t in (self.to_fw.next_release(), self.to_host.next_release()) if t is not None]
        return min(times) if times else None

    @property
    def wants_write(self) -> bool:
        return bool(self.pend_fw or self.pend_host)

    def close(self) -> None:
        self.host.close()
        self.fw.close()


#: a boot check's refusal line from the C firmware (gs_board_boot)
_REFUSAL = re.compile(r"^board: (servo \d+ \(|no servo answers a ping ).*; torque left off")


class _LogReader:
    """Splits the firmware's log channel into stderr lines, frame records and counters."""

    def __init__(self, err: IO[str], log_path: str | None, schema: WireSchema, *, can_channel: str | None = None) -> None:
        self.err = err
        self.schema = schema  # the robot's wire schema: the firmware's frames are in it
        self.buf = bytearray()
        self.stats: dict[str, int] = {}
        #: a CAN link's frame log (python-can's writers by suffix, as the Python board's) from the "C" records
        self.log: FrameLogWriter | None = None
        if log_path:
            self.log = (open_frame_log(log_path, "can", channel=can_channel) if can_channel is not None
                        else open_frame_log(log_path, "serial", schema=schema))
        self.lines = 0
        self.chardevs: dict[str, str] = {}  # QEMU's "char device redirected to X (label L)" (on its stdout)
        self.booted = False  # the firmware's boot line came (its devices are found)
        #: a boot check's refusal ("board: servo 4 (wrist_flex) ...; torque left off") is said as the Python board
        #: says it: "board: servo bus PORT: servo 4 ..." (host.link.board_process knows that line)
        self.refusal_prefix = "board: servo bus: "
        self.refused: str | None = None
        self.ticks: list[int] = []  # every control tick's cost in core clock cycles (a trace build's K records)

    def feed(self, data: bytes) -> None:
        self.buf += data
        while True:
            end = self.buf.find(b"\n")
            if end < 0:
                if len(self.buf) > 1 << 16:  # a runaway line: pass it on rather than grow
                    self._line(bytes(self.buf))
                    self.buf.clear()
                return
            line = bytes(self.buf[:end]).rstrip(b"\r")
            del self.buf[: end + 1]
            self._line(line)

    def _line(self, raw: bytes) -> None:
        self.lines += 1
        text = raw.decode("utf-8", "replace")
        if text.startswith("F ") and self.log is not None:
            parts = text.split(" ")
            if len(parts) == 4 and parts[1] in ("rx", "tx"):
                try:
                    t, raw = int(parts[2]) / 1e6, bytes.fromhex(parts[3])
                except ValueError:
                    print(f"board: unreadable frame record from the firmware: {text[:80]}", file=self.err, flush=True)
                    return
                self.log.write_serial(parts[1], t, raw)  # decoded here from the firmware's raw bytes
            return
        if text.startswith("C ") and self.log is not None:
            frame = parse_can_record(text)
            if frame is None:
                print(f"board: unreadable CAN frame record from the firmware: {text[:80]}", file=self.err, flush=True)
            else:
                self.log.write_can(frame[0], frame[1])  # wall-clock time, as the Python board's CAN log
            return
        m = _CHARDEV.search(text)
        if m:
            self.chardevs[m.group(2)] = m.group(1)
            return
        if text.startswith("K ") and text[2:].isdigit():  # a trace build's tick cost (build kind stm32f4-trace)
            self.ticks.append(int(text[2:]))
            return
        if text.startswith("S "):
            for item in text[2:].split():
                k, _, v = item.partition("=")
                if v.isdigit():
                    self.stats[k] = int(v)
            return
        if " C firmware, " in text:
            self.booted = True
        if not self.booted and _REFUSAL.match(text):
            text = self.refusal_prefix + text.removeprefix("board: ")
            self.refused = text
        if text:
            print(text, file=self.err, flush=True)

    def close(self) -> None:
        if self.buf:
            self._line(bytes(self.buf))
            self.buf.clear()
        if self.log is not None:
            self.log.close()
            self.log = None


def run_firmware(opts: LaunchOptions, err: IO[str] | None = None) -> int:
    """Build, boot and serve until SIGTERM/SIGINT; 130 (stopped by that signal, cleanly: the exit status
    table's "interrupted"), 1 (the firmware died) or 2 (cannot start)."""
    err = sys.stderr if err is None else err
    link = opts.link
    kind = link_kind(link) if link is not None else None
    if kind is not None and opts.firmware not in kind.firmwares:
        print(f"board: {_unserved(opts.firmware, kind.wire, str(link))}", file=err)
        return 2
    can = link if kind is not None and kind.wire == "can" else None  # SocketCAN: the firmware's own raw socket
    if can is not None:
        why = _can_unavailable(can.channel or "can0")
        if why is not None:
            print(f"board: cannot open CAN interface {can.channel or 'can0'}: {why}", file=err)
            return 2
    port = link.port if link is not None and can is None else "pty"
    if can is not None and (opts.faults is not None and opts.faults.active or opts.baud):
        print("board: --faults and --baud with the C firmware need --link pty (the line is modelled between two ptys)",
              file=err)
        return 2
    if (opts.faults is not None and opts.faults.active or opts.baud) and port != "pty":
        print("board: --faults and --baud with the C firmware need --link pty (the line is modelled between two ptys)",
              file=err)
        return 2
    if opts.bus_protocol not in BUS_PROTOCOLS:
        print(f"board: bus protocol must be one of {', '.join(BUS_PROTOCOLS)}, got {opts.bus_protocol!r}", file=err)
        return 2
    if opts.estop_torque not in ESTOP_TORQUE:
        print(f"board: estop torque must be one of {', '.join(ESTOP_TORQUE)}, got {opts.estop_torque!r}", file=err)
        return 2
    if opts.servo_bus_port is not None and opts.firmware != "c":
        print("board: a real servo bus (--servo-bus) needs --firmware c: a QEMU guest has no tty to open "
              "(its servo bus is the emulated plant)", file=err)
        return 2
    machine = QEMU_MACHINES.get(opts.firmware)  # None: the native build
    qemu = machine is not None
    if machine is not None:
        target = machine.trace_kind if opts.icount and machine.trace_kind else machine.kind
    else:
        target = "native-asan" if opts.asan else "native"
    try:
        # a real bus: the servo table with the robot's calibration.toml (offsets, directions, calibrated ranges)
        exe = build(target, opts.robot, calibrated=opts.servo_bus_port is not None)
        if qemu:
            require("qemu-system-arm")
    except BuildError as e:
        need = link_overflow(str(e))  # the port's linker script holds the image to its part's flash and RAM
        if need is not None:
            flash, ram = (f"{n:,}".replace(",", " ") for n in need)
            print(f"board: robot {opts.robot.name} does not fit the {target} image's part: it needs {flash} B flash "
                  f"and {ram} B RAM (the part's budget: ghostshell firmware targets); --firmware c runs it", file=err)
        else:
            print(f"board: cannot build the C firmware: {e}", file=err)
        return 2
    except RobotDataError as e:  # a calibration.toml that does not fit the servo table
        print(f"board: {e}", file=err)
        return 2
    if not opts.lockstep:
        # as the Python board does (firmware_sim.priority): the plant, the relay and the firmware (a child
        # inherits nice value and timer slack) must not wait behind other work on a loaded machine
        from firmware_sim.priority import raise_priority, tighten_timer_slack

        print(f"board: {raise_priority()}; {tighten_timer_slack()}", file=err, flush=True)
    plant: PlantBus | None = None
    bus: _SocketBus | None = None
    if opts.servo_bus_port is None:
        world = World(opts.robot, scene=opts.scene, rate_hz=opts.rate_hz, dt=opts.dt)
        # the keyword only when not the default: PlantBus before Dynamixel support knows no `protocol`
        proto_kw: dict[str, Any] = {"protocol": opts.bus_protocol} if opts.bus_protocol != "sts" else {}
        plant = PlantBus(world, lockstep=opts.lockstep, **proto_kw)
        for sid, at in opts.dead_servos:
            plant.kill(sid, int(at * 1e6))
        # the firmware's bus is a socketpair (no tty layer: see _SocketBus), QEMU's too (a socket chardev)
        bus = _SocketBus()
        bus_arg = bus.name
    else:  # a real servo bus: the firmware opens the tty, nothing runs here for it
        bus_arg = f"tty:{opts.servo_bus_port}:{opts.servo_bus_baud or DEFAULT_SERVO_BAUD}"

    # QEMU's own pty backend notices its peer by polling once a second (the host's first bytes would wait up
    # to 1 s): its UART0 gets a tty device instead, relayed byte for byte to the host's pty
    modelled = opts.faults is not None and opts.faults.active or bool(opts.baud)
    relay = _Relay(opts.baud, opts.faults, opts.fault_seed, fw_socket=qemu) \
        if modelled or (qemu and port == "pty") \
        else None
    host_arg = relay.fw.name if relay is not None else port
    cmd = firmware_command(opts, exe, bus_arg, host_arg)
    if can is not None:  # the host link on SocketCAN (core/can), not a pty
        i = cmd.index("--host")
        cmd[i:i + 2] = ["--can", can.channel or "can0", "--node", str(can.node)] + (["--fd"] if can.fd else [])
    env = dict(os.environ)
    if opts.asan:
        env.setdefault("ASAN_OPTIONS", "detect_leaks=0:abort_on_error=0")
        env.setdefault("UBSAN_OPTIONS", "print_stacktrace=1:halt_on_error=1")
    sockets = [b for b in (bus, relay.fw if relay is not None else None) if isinstance(b, _SocketBus)]
    proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
                            preexec_fn=_die_with_parent, pass_fds=[fd for b in sockets for fd in b.pass_fds])
    for b in sockets:
        b.started()
    assert proc.stdout is not None and proc.stderr is not None
    log_fd = proc.stderr.fileno() if opts.firmware == "c" else proc.stdout.fileno()
    side_fd = proc.stdout.fileno() if opts.firmware == "c" else proc.stderr.fileno()
    for fd in (log_fd, side_fd) + ((bus.master,) if bus is not None else ()):
        os.set_blocking(fd, False)
    logr = _LogReader(err, opts.log_path, schema_for(opts.robot.servo_count),
                      can_channel=(can.channel or "can0") if can is not None else None)
    logr.refusal_prefix = (f"board: servo bus {opts.servo_bus_port}: " if opts.servo_bus_port is not None
                           else "board: servo bus (the emulator's plant): ")
    side = bytearray()
    announced: str | None = None
    if qemu and (relay is not None or port != "pty"):  # no pty of QEMU's to wait for
        side += f"char device redirected to {relay.host.name if relay is not None else port} (label serial0)".encode()
    old = (signal.signal(signal.SIGTERM, _raise_stop), signal.signal(signal.SIGINT, _raise_stop))
    status = 0
    held_fds: list[int] = []
    bus_out = bytearray()
    t_start = time.monotonic()
    try:
        while True:
            now = time.monotonic()
            if announced is None and logr.booted:  # the bus devices are found: the host may talk now
                found = _announcement(opts, bytes(side)) or (logr.chardevs.get("serial0") if qemu
                                                             else None)
                if found is not None:
                    announced = relay.host.name if relay is not None else str(can) if can is not None else found
                    print(f"board: listening on {announced}", flush=True)
                elif now - t_start > 60:
                    print("board: the C firmware did not open its host UART within 60 s", file=err, flush=True)
                    status = 1
                    break
            timeout = 0.5
            times = (plant.next_step_time(), plant.next_release()) if plant is not None else ()
            for t in (*times, relay.next_time() if relay else None):
                if t is not None:
                    timeout = min(timeout, max(0.0, t - now))
            bus_fds = [bus.master] if bus is not None else []
            rfds = bus_fds + [log_fd, side_fd] + (relay.fds() if relay else [])
            wfds = (bus_fds if bus_out else []) + (relay.fds() if relay and relay.wants_write else [])
            try:
                readable, _, _ = select.select(rfds, wfds, [], timeout)
            except InterruptedError:
                continue
            now = time.monotonic()
            for fd in readable:
                if bus is not None and plant is not None and fd == bus.master:
                    data = bus.read()
                    if data:
                        bus_out += plant.feed(data, now)
                elif fd == log_fd:
                    data = _read(fd)
                    if data:
                        logr.feed(data)
                elif fd == side_fd:
                    data = _read(fd)
                    if data:
                        side += data
                        if announced is not None and qemu:
                            _pass_lines(side, err)
                        elif len(side) > 1 << 16:
                            del side[: len(side) - 4096]
                elif relay is not None:
                    relay.on_readable(fd, now)
            if plant is not None and bus is not None:
                plant.step_due(now)
                bus_out += plant.ready(now)
                if bus_out:
                    del bus_out[: bus.write(bytes(bus_out))]
            if relay is not None:
                relay.pump(now)
            if proc.poll() is not None:
                status = proc.returncode
                break
            if logr.refused is not None and qemu:  # the guest idles after its refusal line
                status = 2
                break
    except (_Stop, KeyboardInterrupt):
        status = INTERRUPTED_STATUS
    finally:
        # a second Ctrl-C (or a SIGTERM after it) must not cut the clean shutdown short: ignored until it is done
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        exited = proc.poll() is not None
        # a terminal's Ctrl-C reaches the firmware too (same process group): its exit then is no death
        died = exited and status != INTERRUPTED_STATUS
        if not exited:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(FIRMWARE_STOP_S)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        for fd in (log_fd,):
            while True:
                data = _read(fd)
                if not data:
                    break
                logr.feed(data)
        if plant is not None and bus is not None:  # the stopped firmware's last words (torque off) reach the plant
            plant.feed(bus.read(), time.monotonic())
        logr.close()
        # a boot check refused the start (a servo missing, garbled, of another model, out of range): the
        # firmware's one line "board: servo N (name) ...; torque left off" is all there is to say, and exit 2
        refused = status == 2 and logr.refused is not None
        if refused:
            status = 2
        elif died:
            print(f"board: the C firmware exited with status {proc.returncode}", file=err, flush=True)
            tail = bytes(side[-2000:]).decode("utf-8", "replace").strip()
            if tail and qemu:
                print(tail, file=err, flush=True)
            status = status or 1
        if relay is not None and relay.injectors and opts.faults is not None:
            detected = {k: int(logr.stats.get(k, 0)) for k in STATS_KEYS}
            print("board: faults " + json.dumps({"spec": str(opts.faults), "seed": opts.fault_seed,
                                                 "injected": [i.summary() for i in relay.injectors],
                                                 "board_detected": detected}), file=err, flush=True)
        if plant is not None and not refused:
            print(f"board: {plant.stats.line(plant.world.period_us)}", file=err, flush=True)
        if not opts.lockstep and not refused:
            record = lateness_record(logr.stats, plant)
            print(f"{LATENESS_PREFIX}{json.dumps(record)}", file=err, flush=True)
            warning = lateness_warning(record, 1000 / opts.rate_hz)
            if warning is not None:  # `ghostshell run` repeats a board's warning lines at its end
                print(warning, file=err, flush=True)
        if "tick_cycles_mean" in logr.stats and machine is not None:
            print(f"board: tick cost (virtual-time cycles at {machine.clock_hz / 1e6:g} MHz, bus waits excluded): mean "
                  f"{logr.stats['tick_cycles_mean']}, max {logr.stats.get('tick_cycles_max', 0)}, "
                  f"n {logr.stats.get('tick_cycles_n', 0)}", file=err, flush=True)
        if logr.ticks:  # a trace build's every tick (K records; the S counters above are up to 1 s old)
            ticks = sorted(logr.ticks)
            print(f"board: tick cost per tick (cycles): median {ticks[len(ticks) // 2]}, "
                  f"p99 {ticks[min(len(ticks) - 1, len(ticks) * 99 // 100)]}, max {ticks[-1]}, n {len(ticks)}",
                  file=err, flush=True)
        if relay is not None:
            relay.close()
        for fd in held_fds:
            os.close(fd)
        if bus is not None:
            bus.close()
    signal.signal(signal.SIGTERM, old[0])
    signal.signal(signal.SIGINT, old[1])
    return status


#: the line the launcher ends a realtime run's stderr with: ``board: realtime lateness {json}``
LATENESS_PREFIX = "board: realtime lateness "
#: the firmware's "S" counters that tell lateness (gs_board_log_stats), as the record names them
_FW_LATENESS = {"bus_late_replies": "bus_late_replies", "bus_stalls": "bus_stalls", "bus_tx_dropped": "bus_tx_dropped",
                "ticks_skipped": "board_ticks_skipped",
                "overruns": "board_overruns", "late_frames": "late_frames"}


def lateness_record(fw_stats: dict[str, int], plant: PlantBus | None) -> dict[str, int]:
    """How far a realtime run's board and plant fell behind the wall clock (all ints):
    ``bus_late_replies`` (servo answers that came after the firmware's 10 ms bus deadline),
    ``bus_stalls`` (servo reads nothing answered: the plant or the board was descheduled; not counted
    towards a dead servo), ``bus_tx_dropped`` (bytes the native firmware's bus write gave up on: nobody read
    the bus for 2 ms), ``bus_silent_max_ms`` (longest silence of the whole bus), ``board_ticks_skipped``
    and ``board_overruns`` (the firmware fell >100 ms / >1 tick behind), ``late_frames`` (frames the board
    refused as LATE) and the plant's :meth:`~firmware_sim.plant.bus.PlantLateness.as_dict` (none on a real bus). The firmware's
    counters are its last "S" record (QEMU's image is killed, so up to 1 s old); missing ones are 0."""
    rec = {name: int(fw_stats.get(key, 0)) for key, name in _FW_LATENESS.items()}
    rec["bus_silent_max_ms"] = int(round(fw_stats.get("bus_silent_max_us", 0) / 1000))
    if plant is not None:
        rec.update(plant.lateness.as_dict())
    return rec


#: what counts as "could not keep up" (host.run.realtime_health uses the same figures): ticks skipped to catch
#: up, in ms of board time; the servo bus silent or the plant behind, ms; frames refused LATE
BEHIND_SKIPPED_MS = 100
BEHIND_MS = 100
BEHIND_LATE_FRAMES = 10


def lateness_warning(rec: dict[str, int], tick_ms: float) -> str | None:
    """The one ``board: warning: ...`` line for a realtime run whose board or plant fell substantially behind
    the wall clock (``rec``: :func:`lateness_record`; ``tick_ms``: the control period), else None. It names
    what fell behind and suggests ``--lockstep``; a servo that stayed silent while the bus answered is a
    SERVO_FAULT instead, never this line."""
    parts = []
    skipped_ms = rec.get("board_ticks_skipped", 0) * tick_ms
    if skipped_ms >= BEHIND_SKIPPED_MS:
        parts.append(f"the board skipped {skipped_ms / 1000:.2f} s of ticks to catch up")
    if rec.get("bus_silent_max_ms", 0) >= BEHIND_MS:
        parts.append(f"the servo bus was silent for up to {rec['bus_silent_max_ms']} ms "
                     f"({rec.get('bus_stalls', 0)} reads unanswered, {rec.get('bus_late_replies', 0)} answers late)")
    if rec.get("plant_behind_max_ms", 0) >= BEHIND_MS:
        parts.append(f"the plant fell up to {rec['plant_behind_max_ms']} ms behind")
    if rec.get("late_frames", 0) >= BEHIND_LATE_FRAMES:
        parts.append(f"{rec['late_frames']} frames arrived late")
    if not parts:
        return None
    return ("board: warning: realtime emulation could not keep up on this machine (" + "; ".join(parts)
            + "): that is lateness, not a fault of the robot; rerun with --lockstep for timing that does not "
              "depend on the machine's load")


def _die_with_parent() -> None:
    """In the child before exec: SIGTERM it when this process dies, even by SIGKILL (Linux prctl
    PR_SET_PDEATHSIG), so a killed board never leaves its firmware or QEMU running."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG = 1
    except OSError:
        pass


def _read(fd: int) -> bytes:
    try:
        return os.read(fd, 65536)
    except (BlockingIOError, OSError):
        return b""


def _announcement(opts: LaunchOptions, side: bytes) -> str | None:
    """The host pty the firmware opened: its "board: listening on X" line, or QEMU's chardev line."""
    text = side.decode("utf-8", "replace")
    if opts.firmware == "c":
        m = re.search(r"board: listening on (\S+)", text)
        return m.group(1) if m else None
    for m in _CHARDEV.finditer(text):
        if m.group(2) == "serial0":
            return m.group(1)
    return None


def _pass_lines(buf: bytearray, err: IO[str]) -> None:
    """QEMU's own messages after start: pass complete lines to stderr."""
    while True:
        end = buf.find(b"\n")
        if end < 0:
            return
        line = bytes(buf[:end]).decode("utf-8", "replace").strip()
        del buf[: end + 1]
        if line and not _CHARDEV.search(line):
            print(f"board: qemu: {line}", file=err, flush=True)


def _unserved(firmware: str, wire: str, link: str) -> str:
    """The one line refusing a link the firmware cannot serve (after ``board: ``)."""
    if wire == "can" and firmware == "c":
        return (f"the C firmware serves CAN only on SocketCAN (--link can:socketcan:IF[?node=N&fd=1]), "
                f"not {link}")
    if wire == "can":
        return f"the {firmware} image has no CAN controller (QEMU emulates none); serve {link} with --firmware python or c"
    return f"the {firmware} firmware cannot serve {link}"


def parse_can_record(text: str) -> tuple[str, CanFrame] | None:
    """(direction, frame) of the firmware's CAN frame record ``C rx|tx T_US ID FLAGS HEX`` (core/can/gs_app_can.h:
    hex id, flags 1 FD | 2 extended | 4 remote, data hex), or None when it is malformed."""
    parts = text.split(" ")
    if len(parts) not in (5, 6) or parts[1] not in ("rx", "tx"):
        return None
    try:
        aid, flags = int(parts[3], 16), int(parts[4])
        data = bytes.fromhex(parts[5]) if len(parts) == 6 else b""
    except ValueError:
        return None
    return parts[1], CanFrame(aid, data, is_fd=bool(flags & 1), is_extended_id=bool(flags & 2), is_remote=bool(flags & 4))


def _can_unavailable(channel: str) -> str | None:
    """Why a raw CAN socket cannot be bound to ``channel`` here (the firmware would fail the same way), or None."""
    import socket

    try:
        with socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW) as sock:
            sock.bind((channel,))
    except (OSError, AttributeError) as e:
        return e.strerror or str(e) if isinstance(e, OSError) else "no CAN sockets in this Python"
    return None
