"""How a session reaches its board: the link plan, the emulated board's launch and the link client's connect.

The first steps of :meth:`host.run.robot_session.RobotSession.__aenter__`, in this order:

1. :meth:`LinkPlan.of` decides, before anything starts, what the session connects to: the link spec, whether
   it starts the emulated board on it, the frame logs' suffix, the robot identity the handshake checks, the
   frame grid (µs), the heartbeat interval (s) and the CONFIGs the handshake sends (a slow line's watchdog
   and report rate: :mod:`host.motion.line_cadence`) for the line's baud rate. A link that cannot be used so,
   or a line too slow for the robot at all, raises :class:`~host.link.errors.LinkConfigError` (one line; the CLI exits 2).
2. :func:`launch_board` starts the emulated board (``python -m firmware_sim`` with :func:`board_args`) in a
   worker thread, and stops it again when cancelled while it starts.
3. :func:`connect_client` opens the :class:`~host.link.BoardClient` (HELLO/CAPS) and words its failures:
   a board that died first is a lost link (:class:`~host.link.errors.LinkDown`), not a usage error; a
   handshake that the board's own ``--faults`` broke says so.

Nothing here runs on the control path: it all happens once, before the first frame.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

import anyio.to_thread

from host.link import BoardClient, RobotIdentity
from host.link.board_process import BoardProcess, dead_board_error, start_board
from host.link.errors import HandshakeError, LinkConfigError, RobotMismatch, SchemaMismatch
from host.link.client import HEARTBEAT_S, LinkTarget
from host.motion.line_cadence import LineTooSlow, line_cadence
from host.motion.streamer import GRID_PERIOD_US, frame_wire_bytes
from host.run import artefacts
from host.run.options import SessionOptions
from protocol.framing import encode_frame
from protocol.linkkinds import link_kind
from protocol.linkspec import LinkSpec
from protocol.messages import ConfigKey, Heartbeat
from protocol.wiremodel import BITS_PER_BYTE
from robots.description import Robot

__all__ = ["HEARTBEAT_MAX_S", "LINE_WARN_SHARE", "LinkPlan", "board_args", "connect_client", "heartbeat_for_grid",
           "launch_board", "line_load_note"]

log = logging.getLogger("host.run")


#: the longest heartbeat interval (s), over a line whose frame grid is slow: half the board's default watchdog
HEARTBEAT_MAX_S = 0.1


def heartbeat_for_grid(period_us: int) -> float:
    """The session's heartbeat interval (s) for a frame grid of ``period_us``: :data:`HEARTBEAT_S`, or over a
    slow line (:func:`host.motion.streamer.grid_period_us`) 0.6 of the grid period up to
    :data:`HEARTBEAT_MAX_S`. A realtime streamer sends a frame every period, and every valid message
    feeds the board's watchdog; a heartbeat only fills the gaps. At 4 800 baud (a 12-servo frame every
    170 ms) 50 ms heartbeats came three per gap, 18 per second: with the frames and TIME_SYNCs more than
    the line carries, so frames arrived late and were refused (574 NACKed as LATE in a 2-minute run)."""
    return min(HEARTBEAT_MAX_S, max(HEARTBEAT_S, 0.6 * period_us * 1e-6))


#: the share of a modelled line past which :func:`line_load_note` warns (as the board's telemetry warning)
LINE_WARN_SHARE = 0.8


def line_load_note(n_servos: int, baud: int | None, period_us: int, heartbeat_s: float) -> str | None:
    """One line when the host's steady traffic over a modelled line of ``baud`` (8N1) needs more than
    :data:`LINE_WARN_SHARE` of it, else None. Steady traffic: one full-body frame per grid period and the
    heartbeats that fill each period's gap (one per ``heartbeat_s`` after the frame). At 2 400 baud a
    12-servo robot's frame every 330 ms and three heartbeats need ~2 700 bit/s, 114 % of the line:
    frames queue, arrive late and are refused, and calls do not finish."""
    if not baud:
        return None
    hb_bytes = len(encode_frame(Heartbeat(0), 0))
    beats = max(0, math.ceil(period_us * 1e-6 / heartbeat_s - 1e-9) - 1)
    need = (frame_wire_bytes(n_servos) + beats * hb_bytes) * BITS_PER_BYTE / (period_us * 1e-6)
    if need <= LINE_WARN_SHARE * baud:
        return None
    return (f"--baud {baud}: the frames and heartbeats alone need ~{need:,.0f} bit/s, {need / baud:.0%} of the "
            f"line (more than {LINE_WARN_SHARE:.0%}); frames will arrive late and be refused, and calls may not "
            "finish (raise --baud)")


@dataclass(frozen=True)
class LinkPlan:
    """What a session connects to and how, decided before anything starts (:meth:`of`).

    ``spec``: the link; ``emulate``: start the emulated board on it first; ``log_suffix``: the frame logs'
    (``.jsonl`` on serial, ``.log`` in candump format on CAN); ``identity``: the robot the board must drive
    (HELLO/CAPS); ``period_us``: the frame grid (µs, :func:`host.motion.streamer.grid_period_us`);
    ``heartbeat_s``: the heartbeat interval (s, :func:`heartbeat_for_grid`; half the raised watchdog on a
    slow line); ``lockstep`` and ``wire_baud`` as asked (the board's CAPS decide the clock once connected);
    ``link_config``: the CONFIGs the handshake sends (:meth:`host.motion.line_cadence.LineCadence.config`)."""

    spec: LinkSpec
    emulate: bool
    log_suffix: str
    identity: RobotIdentity
    period_us: int
    heartbeat_s: float
    lockstep: bool
    wire_baud: int | None
    #: CONFIGs the handshake sends: a slow line's watchdog and report rate (host.motion.line_cadence)
    link_config: tuple[tuple[ConfigKey, int], ...] = ()

    @classmethod
    def of(cls, spec: LinkSpec, opts: SessionOptions, robot: Robot) -> LinkPlan:
        """The plan for ``robot`` on ``spec`` with ``opts``; :class:`LinkConfigError` for a link the emulated
        board creates without that board, or an emulated board on a link no second process can join."""
        emulate = opts.emulate_board if opts.emulate_board is not None else spec.implies_emulated_board
        if spec.implies_emulated_board and not emulate:
            raise LinkConfigError(f"{spec} is a link the emulated board creates: it cannot be used without starting the board")
        if emulate and not link_kind(spec).cross_process:
            raise LinkConfigError(f"{spec}: python-can's virtual bus exists inside one process, so an emulated board "
                                  "started as a subprocess cannot join it; use can:slcan:pty, or can:socketcan:vcan0 "
                                  "with --emulate-board (the virtual bus is for in-process tests)")
        try:
            cadence = line_cadence(robot.servo_count, opts.wire_baud)
        except LineTooSlow as e:
            raise LinkConfigError(str(e)) from None
        period_us = cadence.period_us
        return cls(spec, emulate, link_kind(spec).log_suffix,
                   RobotIdentity(robot.name, robot.servo_count, robot.servo_table_hash),
                   period_us, cadence.heartbeat_s() or heartbeat_for_grid(period_us), opts.lockstep, opts.wire_baud,
                   cadence.config())

    def overload_note(self) -> str | None:
        """:func:`line_load_note` for this plan (lockstep sends no heartbeats)."""
        return line_load_note(self.identity.servo_count, self.wire_baud, self.period_us,
                              math.inf if self.lockstep else self.heartbeat_s)

    def grid_note(self) -> str | None:
        """One line when a slow line (``wire_baud``) stretches the frame grid past :data:`GRID_PERIOD_US`, else None."""
        if self.period_us == GRID_PERIOD_US:
            return None
        n = self.identity.servo_count
        return (f"--baud {self.wire_baud}: one {n}-servo frame takes "
                f"{1e3 * frame_wire_bytes(n) * BITS_PER_BYTE / (self.wire_baud or 1):.0f} ms on the line, so the host "
                f"sends one every {self.period_us / 1e3:.0f} ms instead of every {GRID_PERIOD_US / 1e3:.0f} ms (the "
                "board moves the servos in straight lines between them)")


#: the emulated board's command-line flag of each CONFIG key a slow line sets (host.motion.line_cadence)
_BOARD_CONFIG_FLAGS = {ConfigKey.WATCHDOG_MS: "--watchdog-ms", ConfigKey.TELEMETRY_RATE_HZ: "--telemetry-rate"}


def board_args(opts: SessionOptions, robot: Robot, out: Path, scene: str, log_suffix: str) -> list[str]:
    """The emulated board's command-line arguments (``python -m firmware_sim ...``, the link excepted) for
    ``robot`` in ``scene``, its frame log and objects log in ``out``."""
    args = ["--lockstep" if opts.lockstep else "--realtime", "--robot", str(robot.root),
            "--log", str(out / f"board_frames{log_suffix}"), "--scene", scene,
            "--objects-log", str(out / artefacts.OBJECTS_LOG)]
    for push in opts.pushes:
        args += ["--push", push]
    if opts.wire_baud:
        args += ["--baud", str(opts.wire_baud)]
        # a slow line's watchdog and report rate from the start (the handshake sets them again: a real board)
        for key, value in line_cadence(robot.servo_count, opts.wire_baud).config():
            args += [_BOARD_CONFIG_FLAGS[key], str(value)]
    if opts.faults:
        args += ["--faults", opts.faults, "--fault-seed", str(opts.fault_seed)]
    if opts.firmware != "python":
        args += ["--firmware", opts.firmware]
    args += list(opts.servo_bus)  # a real servo bus under the board (docs/guides/hardware.md)
    return args


async def launch_board(args: list[str], stderr_path: Path, spec: LinkSpec) -> BoardProcess:
    """Start the emulated board with ``args`` on ``spec`` (its stderr to ``stderr_path``).

    In a worker thread: a board takes seconds to load its model, and other sessions in this event loop
    (eval --workers) must keep streaming meanwhile. Cancelled while it starts, the board is stopped (it
    must not be left behind). Errors: those of :func:`host.link.board_process.start_board`."""
    started: list[BoardProcess] = []

    def start() -> BoardProcess:
        started.append(start_board(args, stderr_path, link=spec))
        return started[-1]

    try:
        return await anyio.to_thread.run_sync(start)
    except BaseException:
        for board in started:
            board.stop()
        raise


async def connect_client(plan: LinkPlan, target: LinkTarget, *, baud: int, log_path: Path, board: BoardProcess | None,
                         faults: str | None) -> BoardClient:
    """Connect a :class:`BoardClient` to ``target`` (not yet entered) as ``plan`` says, logging frames to
    ``log_path``; ``board``: the board this session started (None: a given one), ``faults``: its
    ``--faults``. Logs :meth:`LinkPlan.overload_note` first.

    Errors: :class:`~host.link.errors.LinkDown` when ``board`` died before its link opened (a lost link, not
    the :class:`LinkConfigError` of a bad spec); a :class:`HandshakeError` that the board's own injected
    faults caused says so; every other error as :meth:`BoardClient.connect` raised it."""
    overload = plan.overload_note()
    if overload:
        log.warning("%s", overload)
    try:
        return await BoardClient.connect(target, baud=baud, log_path=log_path, robot=plan.identity,
                                         wire_baud=plan.wire_baud, heartbeat_s=plan.heartbeat_s,
                                         link_config=plan.link_config)
    except LinkConfigError as e:
        dead = dead_board_error(board, e)  # the board died first: a lost link, not a usage error
        if dead is None:
            raise
        raise dead from e
    except HandshakeError as e:
        if (not (plan.emulate and faults) or isinstance(e, (SchemaMismatch, RobotMismatch))
                or board is None or board.exit_reason() is not None):
            raise
        # the board this run started injects the faults from its first message on: it is there, and
        # the question the error ends with would send the user looking for one
        raise HandshakeError(f"{e} (the board this run started is there: its --faults {faults} "
                             "lost the HELLO/CAPS exchange)") from e
