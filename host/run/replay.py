"""Replay a recorded run: feed its host-to-board traffic into a fresh lockstep board.

``read_host_to_board(path)`` yields ``(t, seq, message)`` for every message the host sent,
in send order, from a frame log; the reader is chosen by the file's suffix in
:data:`LOG_READERS` (``.jsonl``: the serial JSON-Lines log, :mod:`protocol.framelog`;
the CAN transport adds its python-can formats there). ``replay(log, out)`` starts
``python -m firmware_sim --lockstep`` on a pty, sends every recorded message with its
original sequence number through the serial transport, and writes ``summary.json``
(``base_end`` as ``[x m, y m, yaw deg]``, and the original's for comparison) and
``joints.png`` to ``out``.

Why the result matches: a lockstep board handles each message at the board time the
messages before it have covered, so the same message stream gives the same physics
however it was paced (see :mod:`firmware_sim.server`). Pacing: after every ADVANCE the
replay waits for its ACK (as the recording host did), so nothing piles up. The replay
waits for the board to report ground truth at the board time of the last SIM_STATE the
original host received (found in the log), which is what the original ``base_end`` was; when
that time lies past what the recorded messages cover (a realtime board runs on by itself after
the host's last frame), one closing ADVANCE covers it, so the wait always has an end.

Refused up front, before a board starts (:class:`ReplayInputError`, exit status 2): a log with
nothing that moves the board (no SERVO_FRAME, no ADVANCE: a run stopped while starting), a
``--robot`` other than the one the run's summary.json names, and servo frames addressing servos
the robot lacks (a log of another robot: its board would refuse every frame and never move).
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from host.link.board_process import start_board
from host.bounded_read import special_file_problem
from host.link.canlog import CAN_LOG_SUFFIXES, CanLogError, can_last_sim_state, read_can_host_to_board
from host.link.errors import LinkDown, LinkError, LinkTimeout
from host.link.transports import open_transport
from host.run import artefacts
from host.run.artefacts import recorded_robot
from host.run.mcap_log import McapError, RunLog
from host.run.mcap_read import mcap_last_sim_state, read_mcap_host_to_board
from protocol import framelog
from protocol.framing import DecodeError, Frame
from protocol.messages import HOST_TO_BOARD, Ack, Advance, Message, Nack, ServoFrame, SimState, Telemetry
from robots.description import Robot
from robots.registry import DEFAULT_ROBOT, load_robot

log = logging.getLogger("host.run")

__all__ = ["LOG_READERS", "ReplayError", "ReplayInputError", "ReplayResult", "find_host_log", "read_host_to_board",
           "read_serial_log", "replay"]

#: host log file names looked for in a run folder, in order
HOST_LOG_NAMES = ("host_frames.jsonl", "host.jsonl", "host_frames.log", "host_frames.asc", "host_frames.blf", "run.mcap")
#: the files a replay writes into its ``out`` folder
ARTEFACTS = ("board_frames.jsonl", "board.stderr", "host_frames.jsonl", "run.mcap", "joints.png", "summary.json")


class ReplayError(LinkError):
    """The log cannot be replayed (unreadable, nothing sent, or the board did not follow)."""


class ReplayInputError(ReplayError):
    """The log given is no replayable log (missing, no host log in the folder, unknown format,
    unreadable, nothing sent): a bad input, found before the board starts (exit status 2)."""


#: message types only a host sends (names of :data:`protocol.messages.HOST_TO_BOARD`): the ``dir`` of
#: such a record says which way host-to-board traffic runs in a serial frame log
HOST_SENT_TYPES = frozenset(t.name for t in HOST_TO_BOARD)


def host_to_board_dir(path: Path) -> str:
    """``"tx"`` when the serial frame log at ``path`` is the host's (it sent the host's messages), ``"rx"``
    when it is the board's: the ``dir`` of its first record of a type only a host sends
    (:data:`HOST_SENT_TYPES`); ``"tx"`` when it has none."""
    with open(path, encoding="utf-8") as f:
        for rec in framelog.iter_records(f):
            if rec.get("type") in HOST_SENT_TYPES:
                return str(rec["dir"])
    return "tx"


def read_serial_log(path: Path) -> Iterator[tuple[float, int, Message]]:
    """Host-to-board messages of a serial JSON-Lines frame log, the host's (``tx`` records) or the
    board's (``rx``; :func:`host_to_board_dir`), re-decoded from raw bytes (in the log's own wire schema,
    :class:`protocol.framelog.LogDecoder`)."""
    h2b = host_to_board_dir(path)
    dec = framelog.LogDecoder()
    with open(path, encoding="utf-8") as f:
        for rec in framelog.iter_records(f):
            if "error" in rec:
                continue
            if rec["dir"] != h2b:
                if rec.get("type") == "CAPS":
                    dec.decode(rec["raw"])  # the board's answer names the schema too
                continue
            item = dec.decode(rec["raw"])
            if isinstance(item, Frame):
                yield float(rec["t"]), item.seq, item.msg


def _serial_last_sim_state(path: Path) -> SimState | None:
    b2h = "rx" if host_to_board_dir(path) == "tx" else "tx"  # the host received it / the board sent it
    last: SimState | None = None
    with open(path, encoding="utf-8") as f:
        for rec in framelog.iter_records(f):
            if rec["dir"] == b2h and rec.get("type") == "SIM_STATE":
                item = framelog.decode_raw(rec["raw"])  # SIM_STATE is the same in every wire schema
                if isinstance(item, Frame) and isinstance(item.msg, SimState):
                    last = item.msg
    return last


#: suffix -> reader of host-to-board messages ``(t, seq, message)``; CAN: python-can's formats
LOG_READERS: dict[str, Callable[[Path], Iterator[tuple[float, int, Message]]]] = {
    ".jsonl": read_serial_log,
    **{suffix: read_can_host_to_board for suffix in CAN_LOG_SUFFIXES},
    ".mcap": read_mcap_host_to_board,  # the run's MCAP: its /link/tx channel (host.run.mcap_log)
}
#: suffix -> the last ground truth the recording host received (None if the format cannot say)
LAST_SIM_STATE: dict[str, Callable[[Path], SimState | None]] = {
    ".jsonl": _serial_last_sim_state,
    **{suffix: can_last_sim_state for suffix in CAN_LOG_SUFFIXES},
    ".mcap": mcap_last_sim_state,
}


def find_host_log(path: Path) -> Path:
    """``path`` itself, or the host log inside a run folder; :class:`ReplayError` if there is none."""
    if path.is_dir():
        for name in HOST_LOG_NAMES:
            if (path / name).is_file():
                return path / name
        found = sorted(p for p in path.iterdir() if p.name.startswith("host") and p.suffix in LOG_READERS)
        if found:
            return found[0]
        raise ReplayInputError(f"no host frame log in {path} (looked for {', '.join(HOST_LOG_NAMES)})")
    problem = special_file_problem(path)  # /dev/zero, a FIFO: endless or blocking, never a log
    if problem is not None:
        raise ReplayInputError(problem)
    if not path.is_file():
        raise ReplayInputError(f"no such log: {path}")
    return path


def _check_not_over_the_recording(log_path: Path, out: Path) -> None:
    """:class:`ReplayInputError` when writing the replay's artefacts into ``out`` would overwrite the recording.

    That is when ``out`` is the folder of the log replayed (as named, or the folder of the file a
    symbolic link names) and already holds one of :data:`ARTEFACTS` (a run folder: its logs, summary and
    plots; the log itself may be one of them), or when one of those files in ``out`` is the log itself
    (a hard link). Found by new users: ``replay runs/x --out runs/x``, then through a symbolic link."""
    if not out.is_dir():
        return
    existing = [out / name for name in ARTEFACTS if (out / name).exists()]
    folders = {log_path.parent.resolve(), log_path.resolve().parent}
    same = [p for p in existing if os.path.samefile(p, log_path)]
    if out.resolve() in folders and existing or same:
        clash = ", ".join(p.name for p in (existing if out.resolve() in folders else same))
        raise ReplayInputError(f"the replay would write its artefacts into {out}, the folder of the log it replays, "
                               f"over the recording's {clash}; give another folder with --out DIR")


def read_host_to_board(path: Path) -> Iterator[tuple[float, int, Message]]:
    """``(t, seq, message)`` the host sent, in order, from the log at ``path`` (reader by suffix)."""
    reader = LOG_READERS.get(path.suffix.lower())
    if reader is None:
        raise ReplayInputError(f"cannot replay {path.name}: unknown log format {path.suffix!r} "
                          f"(known: {', '.join(sorted(LOG_READERS))})")
    if path.suffix.lower() == ".log":
        from host.link.canlog import candump_cut_line, candump_problem

        problem = candump_problem(path)
        if problem is not None:
            raise ReplayInputError(f"cannot replay it: {problem}")
        cut = candump_cut_line(path)
        if cut is not None:  # what came before it replays; the cut frame is not guessed at
            log.warning("%s:%d is cut off (no newline at its end: the logger stopped while writing it); "
                        "replaying the whole frames before it", path, cut)
    try:
        yield from reader(path)
    except CanLogError as e:  # python-can's reader failed: the message names the file and why
        raise ReplayInputError(f"cannot replay it: {e}") from None
    except (ValueError, UnicodeDecodeError) as e:  # a file with a log's name that is not that log
        raise ReplayInputError(f"cannot replay {path.name}: not a readable {path.suffix} frame log ({e})") from None


def _pose(s: SimState | None) -> list[float] | None:
    if s is None:
        return None
    return [round(s.base_pos[0], 4), round(s.base_pos[1], 4), round(artefacts.yaw_deg(s.base_quat), 2)]


@dataclass
class ReplayResult:
    """What a replay produced (also in ``out/summary.json``)."""

    base_end: list[float] | None
    original_base_end: list[float] | None
    base_end_error_mm: float | None
    messages: int
    board_time_s: float
    out: Path
    sim_states: list[SimState] = field(default_factory=list, repr=False)


#: us a closing ADVANCE covers past the board time waited for: one 50 Hz telemetry period, so a report is due
TAIL_US = 20_000


def _check_servos(msgs: list[tuple[float, int, Message]], robot: Robot, log_path: Path) -> None:
    """:class:`ReplayInputError` when the log's servo frames address servos ``robot`` lacks (a log of
    another robot: the board would refuse every frame and never move)."""
    for _, seq, msg in msgs:
        if isinstance(msg, ServoFrame) and (msg.mask & ~robot.servos.all_mask or len(msg.targets) > robot.servo_count):
            raise ReplayInputError(
                f"{log_path} drives servos that robot {robot.name!r} ({robot.servo_count} servos) lacks "
                f"(SERVO_FRAME seq {seq}: mask 0x{msg.mask:04x}, {len(msg.targets)} targets); "
                f"give --robot the robot the run drove")


#: the latest board time (s) a replayable log's first servo frame or ADVANCE may name, for a lockstep
#: log (one with ADVANCEs) and a realtime one: the replay's board is fresh (its clock at 0, its robot
#: standing where a board starts it), as is the board a run starts for itself. A lockstep board's clock
#: waits for the host, so its first frame is due within the lookahead (0.03-0.1 s); a realtime board's
#: runs from its start, so the first frame comes after the handshake on the wall clock (0.03-0.45 s on
#: a quiet machine, bench_latency's logs; more on a loaded one)
MAX_FIRST_BOARD_S = {"lockstep": 1.0, "realtime": 10.0}


def _check_fresh_board(msgs: list[tuple[float, int, Message]], log_path: Path) -> None:
    """:class:`ReplayInputError` when the log was recorded on a board that had been running before its
    run (a board you started, a second run on one): its first frame is due seconds into the board's
    time. A fresh board would run to that time without a frame, hold and latch its watchdog fault, and
    refuse every frame; the replay then waited out its timeout and blamed the board."""
    limit_s = MAX_FIRST_BOARD_S["lockstep" if any(isinstance(m, Advance) for _, _, m in msgs) else "realtime"]
    for _, _, msg in msgs:
        t_us = msg.apply_at_us if isinstance(msg, ServoFrame) else msg.until_us if isinstance(msg, Advance) else None
        if t_us is None:
            continue
        if t_us > limit_s * 1e6:
            raise ReplayInputError(
                f"cannot replay {log_path}: its first frame is due at board time {t_us / 1e6:.3f} s, so it was "
                f"recorded on a board that had been running before the run (one you started, or a second run on "
                f"one); the robot's state when the run began is not in the log, and a fresh board would hold its "
                f"servos until then. Replay a run that started its own board")
        return


def _replay_log(path: Path, robot: Robot, log_path: Path) -> RunLog | None:
    """The replay's own run.mcap (one warning line and none when it cannot be written)."""
    try:
        return RunLog.create(path, robot, {"label": f"replay of {log_path}", "clock_mode": "lockstep"})
    except McapError as e:
        log.warning("ghostshell: no run.mcap: %s; the replay goes on without it", e)
        return None


async def _replay(log_path: Path, out: Path, timeout_s: float, robot_name: str, robots_dir: str | None) -> ReplayResult:
    msgs = list(read_host_to_board(log_path))
    if not msgs:
        raise ReplayInputError(f"{log_path} holds no host-to-board messages")
    if not any(isinstance(m, (ServoFrame, Advance)) for _, _, m in msgs):
        raise ReplayInputError(f"nothing to replay: {log_path} holds no servo frame and no ADVANCE "
                               f"(the run stopped before it moved the robot)")
    robot = load_robot(robot_name, robots_dir)
    _check_servos(msgs, robot, log_path)
    _check_fresh_board(msgs, log_path)
    out.mkdir(parents=True, exist_ok=True)  # only for a log that can be replayed
    last_fn = LAST_SIM_STATE.get(log_path.suffix.lower())
    original = last_fn(log_path) if last_fn is not None else None
    board = start_board(["--lockstep", "--robot", str(robot.root), "--log", str(out / "board_frames.jsonl")],
                        out / "board.stderr")
    transport = open_transport(board.spec, log_path=out / "host_frames.jsonl", servo_count=robot.servo_count)
    run_log = _replay_log(out / "run.mcap", robot, log_path)
    acks: dict[int, asyncio.Future[Message]] = {}
    tel_t: list[float] = []
    tel_q: list[tuple[float, ...]] = []
    sims: list[SimState] = []
    progress = asyncio.Event()
    lost: list[str] = []

    def on_receive(items: object) -> None:
        for item in items:  # type: ignore[attr-defined]
            if isinstance(item, DecodeError):
                continue
            m = item.msg
            if run_log is not None:
                run_log.on_message(m)
            if isinstance(m, Telemetry):
                if len(tel_t) < 200_000:
                    tel_t.append(m.board_time_us * 1e-6)
                    tel_q.append(m.positions)
            elif isinstance(m, SimState):
                sims.append(m)
                del sims[:-2]
                progress.set()
            elif isinstance(m, (Ack, Nack)):
                fut = acks.pop(m.ack_seq, None)
                if fut is not None and not fut.done():
                    fut.set_result(m)

    def on_lost(reason: str) -> None:
        lost.append(reason)
        progress.set()
        for fut in acks.values():
            if not fut.done():
                fut.set_exception(LinkDown(f"board link lost during the replay: {reason}"))

    targets: list[tuple[float, tuple[float, ...]]] = []
    end_us = 0
    try:
        await transport.connect(on_receive, on_lost)
        loop = asyncio.get_running_loop()
        for _, seq, msg in msgs:
            fut: asyncio.Future[Message] | None = None
            if isinstance(msg, Advance):
                fut = loop.create_future()
                acks[seq] = fut
                end_us = max(end_us, msg.until_us)
            if isinstance(msg, ServoFrame):
                end_us = max(end_us, msg.apply_at_us)
                if msg.mask == robot.servos.all_mask and len(msg.targets) == robot.servo_count:
                    targets.append((msg.apply_at_us * 1e-6, msg.targets))
            transport.send(msg, seq)
            if run_log is not None:
                run_log.on_frame_sent(seq, msg, end_us)
            if fut is not None:
                try:
                    await asyncio.wait_for(fut, timeout_s)
                except TimeoutError:
                    raise ReplayError(f"the board did not acknowledge ADVANCE (seq {seq}) within {timeout_s} s") from None
        want_us = original.board_time_us if original is not None else end_us - 40_000
        if want_us > end_us:  # e.g. a realtime run's board ran on past the host's last frame: cover it,
            # or a lockstep board could never report that time (the last targets hold meanwhile, as they did)
            seq = (max(s for _, s, _ in msgs) + 1) & 0xFFFF
            fut = loop.create_future()
            acks[seq] = fut
            transport.send(Advance(want_us + TAIL_US), seq)
            end_us = want_us + TAIL_US
            try:
                await asyncio.wait_for(fut, timeout_s)
            except TimeoutError:
                raise ReplayError(f"the board did not acknowledge the closing ADVANCE within {timeout_s} s") from None
        while not (sims and sims[-1].board_time_us >= want_us):
            if lost:
                raise ReplayError(f"board link lost during the replay: {lost[0]}")
            progress.clear()
            try:
                await asyncio.wait_for(progress.wait(), timeout_s)
            except TimeoutError:
                raise LinkTimeout(f"the board did not reach board time {want_us / 1e6:.3f} s "
                                  f"(last report {sims[-1].board_time_us / 1e6 if sims else 0:.3f} s)") from None
        final = sims[-1]
        if original is not None:
            final = next((s for s in sims if s.board_time_us == original.board_time_us), final)
    finally:
        transport.close()
        board.stop()
        if run_log is not None:
            run_log.close()
    base_end, orig_end = _pose(final), _pose(original)
    err_mm = None
    if original is not None:
        err_mm = round(1000 * math.dist(final.base_pos[:2], original.base_pos[:2]), 3)
    if tel_t:
        names = robot.servos.names
        tgt = (np.asarray([t for t, _ in targets]), np.asarray([q for _, q in targets])) if targets else None
        artefacts.plot_joints(out / "joints.png", np.asarray(tel_t), np.asarray(tel_q), names, tgt,
                              groups=artefacts.joint_groups(robot))
    summary = {"replay_of": str(log_path), "messages": len(msgs), "base_end": base_end,
               "original_base_end": orig_end, "base_end_error_mm": err_mm,
               "board_time_s": round(final.board_time_us / 1e6, 6)}
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    return ReplayResult(base_end, orig_end, err_mm, len(msgs), final.board_time_us / 1e6, out, sims)


def _check_robot(run_dir: Path, recorded: str, asked: str, robots_dir: str | None) -> None:
    """:class:`ReplayInputError` when the robot asked for is not the one the run drove (by name)."""
    was, now = load_robot(recorded, robots_dir), load_robot(asked, robots_dir)
    if was.name != now.name:
        raise ReplayInputError(f"{run_dir} was recorded on robot {was.name!r} ({was.servo_count} servos): it cannot be "
                               f"replayed on {now.name!r} ({now.servo_count} servos); leave out --robot")


def replay(log: str | Path, out: str | Path, *, timeout_s: float = 30.0, robot: str | None = None,
           robots_dir: str | None = None) -> ReplayResult:
    """Replay the host log ``log`` (a file or a run folder) into a fresh lockstep board; artefacts in ``out``.

    ``robot``: the robot the board drives (default: the one the recorded run's summary.json names,
    else :data:`robots.registry.DEFAULT_ROBOT`). Raises :class:`ReplayError` / :class:`LinkError` with
    the reason, ``RuntimeError`` if the board does not start, :class:`protocol.framelog.FrameLogError`
    for an unreadable log, :class:`robots.description.RobotDataError` for an unknown robot.
    """
    log_path = find_host_log(Path(log))
    out_dir = Path(out)
    _check_not_over_the_recording(log_path, out_dir)
    recorded = recorded_robot(log_path.parent)
    if robot is not None and recorded is not None:
        _check_robot(log_path.parent, recorded, robot, robots_dir)
    name = robot or recorded or DEFAULT_ROBOT
    return asyncio.run(_replay(log_path, out_dir, timeout_s, name, robots_dir))
