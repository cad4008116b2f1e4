"""The lockstep server's link work runs while the native kernel ticks on its own thread
(:meth:`firmware_sim.native.NativeTick.run_during`, :meth:`firmware_sim.board.Board.run` with ``during``,
:meth:`firmware_sim.server.BoardServer._link_work`): the ticks, the reports and the frame log are what they
were without the overlap."""

from __future__ import annotations

import json
import os
import select
import threading
from pathlib import Path

import numpy as np
import pytest
import serial

from firmware_sim.board import OVERLAP_MIN_TICKS, Board
from firmware_sim.board_reports import DeferredReports
from firmware_sim.config import BoardConfig
from firmware_sim.native import native_reason
from firmware_sim.server import OVERLAP_ENV, BoardServer
from firmware_sim.transports.serial import SerialBoardTransport
from protocol.codec import SCHEMA_HASH, schema_for
from protocol.framing import Frame, FrameDecoder, encode_frame
from protocol.messages import PROTOCOL_VERSION, FaultFlags, Hello, Message, ServoFrame, SimState, Telemetry


def _require_native() -> None:
    reason = native_reason()
    if reason is not None:
        pytest.skip(f"native kernel unavailable: {reason}")


def _stream(b: Board, n: int) -> list[ServoFrame]:
    """``n`` frames at 50 Hz moving every servo (a 1 Hz sine of 0.2 rad around neutral)."""
    neutral = np.array(b.table.neutral)
    return [ServoFrame(k * 20_000, b.table.all_mask,
                       tuple(np.clip(neutral + 0.2 * np.sin(2 * np.pi * k / 50), b.table.mins, b.table.maxs).tolist()))
            for k in range(1, n + 1)]


def _drive(b: Board, frames: list[ServoFrame], during: object = None) -> list[Message]:
    """The lockstep server's order on ``b``: tick while it can, else handle the next frame; the reports."""
    out: list[Message] = []
    k = 0
    while k < len(frames) or b.can_tick():
        if b.can_tick():
            _, got = b.run(256) if during is None else b.run(256, during=during)  # type: ignore[arg-type]
            out += got
        else:
            b.handle(frames[k], k + 1)
            k += 1
    return out


def test_ticks_overlapped_with_link_work_are_the_plain_ones() -> None:
    """``Board.run(during=...)``: the same reports and the same MjData, bit for bit, as ``Board.run()``;
    ``during`` runs once per batch with the batch's length, on the kernel's thread for long batches."""
    _require_native()
    boards = [Board(BoardConfig(lockstep=True, kernel="native!")) for _ in range(2)]
    for b in boards:
        b.handle(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 0), 0)
    frames = _stream(boards[0], 150)
    calls: list[int] = []
    report = boards[1].telemetry()

    def during(n: int) -> None:
        calls.append(n)
        encode_frame(report, n)  # Python work meanwhile (never the board's own state: the ticks' own)

    plain = _drive(boards[0], frames)
    overlapped = _drive(boards[1], frames, during)
    assert plain == overlapped
    assert boards[0].ticks == boards[1].ticks > 1000
    for name in ("qpos", "qvel", "act", "ctrl", "qacc_warmstart"):
        assert np.array_equal(getattr(boards[0].data, name), getattr(boards[1].data, name)), name
    assert sum(calls) == boards[1].ticks  # once per batch, with its length
    assert any(n >= OVERLAP_MIN_TICKS for n in calls)
    assert boards[1].native is not None and boards[1].native._worker is not None  # a kernel thread ran them
    boards[1].native.close()
    assert boards[1].native._worker is None


def test_an_exception_in_the_link_work_comes_after_the_ticks_are_counted() -> None:
    _require_native()
    b = Board(BoardConfig(lockstep=True, kernel="native!"))
    b.handle(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 0), 0)
    for k, f in enumerate(_stream(b, 5), 1):
        b.handle(f, k)

    def boom(n: int) -> None:
        if n >= OVERLAP_MIN_TICKS:
            raise OSError("link gone")

    with pytest.raises(OSError, match="link gone"):
        while b.can_tick():
            b.run(256, during=boom)
    ref = Board(BoardConfig(lockstep=True, kernel="python"))
    ref.handle(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 0), 0)
    for k, f in enumerate(_stream(ref, 5), 1):
        ref.handle(f, k)
    for _ in range(b.ticks):
        ref.tick()
    assert b.now_us == ref.now_us and np.array_equal(b.data.qpos, ref.data.qpos)  # clock and physics agree
    assert b.native is not None
    b.native.close()


@pytest.mark.parametrize("overlap", [True, False], ids=["overlap", "no-overlap"])
def test_a_served_lockstep_board_logs_its_reports_at_the_board_time_they_were_made(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, overlap: bool) -> None:
    """Over a pty, reports held back to be encoded while the next ticks run are logged at the board time
    they were made (TELEMETRY's own time), their bytes are the plain board's reports, and the kernel's
    thread is gone once the server stops; the same without the overlap ($GHOSTSHELL_LOCKSTEP_OVERLAP=0)."""
    _require_native()
    monkeypatch.setenv(OVERLAP_ENV, "1" if overlap else "0")
    log = tmp_path / "board.jsonl"
    board = Board(BoardConfig(lockstep=True, kernel="native!"))
    transport = SerialBoardTransport("pty", log_path=str(log), servo_count=board.n)
    server = BoardServer(board, transport)
    assert server.overlap is overlap
    frames = _stream(board, 100)
    served = threading.Thread(target=server.serve)
    served.start()
    got: list[Message] = []
    try:
        with serial.Serial(transport.name, 115200, timeout=0) as ser:
            fd = ser.fileno()
            ser.write(encode_frame(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 0), 0) + b"".join(
                encode_frame(f, k, schema_for(board.n)) for k, f in enumerate(frames, 1)))
            dec = FrameDecoder(schema=schema_for(board.n))
            while not any(isinstance(m, Telemetry) and m.board_time_us >= 100 * 20_000 for m in got):
                assert select.select([fd], [], [], 30.0)[0], "the board stopped reporting"
                try:
                    got += [f.msg for f in dec.feed(os.read(fd, 65536)) if isinstance(f, Frame)]
                except BlockingIOError:
                    pass
    finally:
        server.stop()
        served.join(timeout=30)
        transport.close()
    assert not served.is_alive()
    assert board.native is not None and board.native._worker is None  # the kernel's thread ended with serve()
    reports = [m for m in got if isinstance(m, (Telemetry, SimState))]
    ref = Board(BoardConfig(lockstep=True, kernel="native!"))
    ref.handle(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 0), 0)
    wire = schema_for(ref.n)
    want = [wire.quantize_message(m) for m in _drive(ref, [wire.quantize_message(f) for f in frames])]  # type: ignore[misc]
    assert reports == want[:len(reports)] and len(reports) >= 200
    tx = [json.loads(line) for line in log.read_text().splitlines()]
    tel = [r for r in tx if r["dir"] == "tx" and r["type"] == "TELEMETRY"]
    assert len(tel) >= 100
    assert all(r["t"] == r["fields"]["board_time_us"] / 1e6 for r in tel), [
        (r["t"], r["fields"]["board_time_us"]) for r in tel if r["t"] != r["fields"]["board_time_us"] / 1e6][:3]


def test_deferred_reports_are_the_reports_the_board_would_have_made() -> None:
    """``Board.defer_reports``: each report period gives one DeferredReports whose ``messages()``, built
    after the board has ticked on, are the TELEMETRY and SIM_STATE a plain board made at that time."""
    boards = [Board(BoardConfig(lockstep=True, robot="arm")) for _ in range(2)]
    for b in boards:
        b.handle(Hello(PROTOCOL_VERSION, boards[0].wire_schema.hash, 0), 0)
    boards[1].defer_reports = True
    frames = _stream(boards[0], 60)
    plain = _drive(boards[0], frames)
    deferred = _drive(boards[1], frames)
    assert deferred and all(isinstance(d, DeferredReports) for d in deferred)
    built = [m for d in deferred for m in d.messages()]  # type: ignore[attr-defined]
    assert built == plain and len(plain) >= 100


def _jumpy(b: Board, n: int) -> list[ServoFrame]:
    """``n`` frames at 50 Hz holding every servo for 10 frames, then 0.3 rad away for 10: speed clamps in
    the report periods after a jump, none in the others (CLAMPED must land in the right TELEMETRY)."""
    neutral = np.array(b.table.neutral)
    return [ServoFrame(k * 20_000, b.table.all_mask,
                       tuple(np.clip(neutral + 0.3 * (k // 10 % 2), b.table.mins, b.table.maxs).tolist()))
            for k in range(1, n + 1)]


def _edge(b: Board, n: int) -> list[ServoFrame]:
    """``n`` frames at 50 Hz alternating every servo between its upper limit and 1.05e-9 rad past it: the ramp
    between them stays within the board's 1e-9 rad limit tolerance, only the tick at a frame past the limit
    clamps. That tick is the first after a report: its CLAMPED belongs in the next TELEMETRY, not that one."""
    hi = np.array(b.table.maxs)
    return [ServoFrame(k * 20_000, b.table.all_mask, tuple((hi + 1.05e-9 * (k % 2)).tolist())) for k in range(1, n + 1)]


def _random(b: Board, n: int) -> list[ServoFrame]:
    """``n`` frames 2 to 30 ms apart on the tick grid, each moving every servo up to 0.1 rad from neutral at
    random (seeded): batches of every length, clamps that end anywhere in a report period."""
    rng = np.random.default_rng(7)
    neutral = np.array(b.table.neutral)
    t, out = 0, []
    for _ in range(n):
        t += int(rng.integers(1, 16)) * 2000
        q = np.clip(neutral + rng.uniform(-0.1, 0.1, b.n), b.table.mins, b.table.maxs)
        out.append(ServoFrame(t, b.table.all_mask, tuple(q.tolist())))
    return out


@pytest.mark.parametrize("robot", ["coco", "arm"])
@pytest.mark.parametrize("make", [_stream, _jumpy, _edge, _random], ids=["sine", "jumps", "edge", "random"])
def test_a_split_run_is_the_two_runs_it_replaces(robot: str, make: object) -> None:
    """With deferred reports and link work (the lockstep server's overlap), the ticks up to a report and the
    quiet ticks after it run as one native job (``Board._run_split``: the report's snapshot taken in C
    between them, the frames due at the second part applied there): the same reports, the same MjData
    and board state, bit for bit, as the plain board's ``run`` calls; one batch per report period."""
    _require_native()
    boards = [Board(BoardConfig(lockstep=True, robot=robot, kernel="native!")) for _ in range(2)]
    for b in boards:
        b.handle(Hello(PROTOCOL_VERSION, b.wire_schema.hash, 0), 0)
    boards[1].defer_reports = True
    frames = make(boards[0], 120 if make is not _random else 400)  # type: ignore[operator]
    calls: list[int] = []
    plain = _drive(boards[0], frames)
    split = _drive(boards[1], frames, calls.append)
    assert all(isinstance(d, DeferredReports) for d in split)
    assert [m for d in split for m in d.messages()] == plain and len(plain) >= 200  # type: ignore[attr-defined]
    a, b = boards
    assert (a.ticks, a.now_us, a.clamped_ticks, a.last_applied_seq, len(a.buffer)) == \
        (b.ticks, b.now_us, b.clamped_ticks, b.last_applied_seq, len(b.buffer))
    assert a.safety.last_feed_us == b.safety.last_feed_us
    for name in ("qpos", "qvel", "act", "ctrl", "qacc_warmstart"):
        assert np.array_equal(getattr(a.data, name), getattr(b.data, name)), name
    for name in ("anchor_t", "anchor_v", "next_ok", "next_t", "next_v"):
        assert np.array_equal(getattr(a.stream, name), getattr(b.stream, name)), name
    if make in (_jumpy, _edge):
        assert any(t.faults & FaultFlags.CLAMPED for t in plain if isinstance(t, Telemetry))
        assert not all(t.faults & FaultFlags.CLAMPED for t in plain if isinstance(t, Telemetry))
    assert sum(calls) == b.ticks
    if make is not _random:
        assert calls.count(b._telemetry_every) >= 100  # one job per report period
    assert b.native is not None
    b.native.close()
