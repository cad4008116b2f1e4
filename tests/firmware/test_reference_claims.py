"""The board behaviour docs/wire-protocol.md states (firmware_sim/wire_reference.py), checked on the Python board core
(lockstep, direct handle()/tick() calls): start-up, ESTOP and the jitter buffer, where a sparse keyframe's
interpolation starts, edge and level fault flags, the CONFIG keys table, the message table's wording, and the
one undecodable frame the board answers (board.answerable). The same refusals over a pty on both boards:
tests/cfirmware/test_wire_refusals.py."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from firmware_sim.board import Board, answerable
from firmware_sim.config import BoardConfig
from firmware_sim.wire_reference import CONFIG_RANGES, I32_MAX, MEANING, render
from protocol.framing import DecodeError, DecodeErrorKind, Frame, FrameDecoder, encode_raw_frame
from protocol.messages import (
    Ack, Advance, Config, ConfigKey, Estop, EstopClear, FaultFlags, MsgType, Nack, NackReason, ServoFrame,
)

from .conftest import make_board, run

HEAD_YAW = 8  # servo id 9


def _frame(t_us: int, value: float) -> ServoFrame:
    return ServoFrame(t_us, 1 << HEAD_YAW, (value,))


def test_start_up_state() -> None:
    """Board time 0, neutral pose commanded, nothing applied, no flags, watchdog unarmed; a lockstep board does
    not tick (so sends nothing) before the host's first ADVANCE or frame, a realtime board does."""
    board = Board(BoardConfig(lockstep=True))
    tel = board.telemetry()
    assert (tel.board_time_us, tel.last_applied_seq, tel.faults, tel.buffer_fill) == (0, 0, FaultFlags.NONE, 0)
    assert (tel.late_count, tel.dropped_count, tel.link_errors) == (0, 0, 0)
    assert np.allclose(board.servo.cmd, board.table.neutral)
    assert not board.safety.armed and not board.can_tick()
    board.handle(Advance(2_000), 1)
    assert board.safety.armed and board.can_tick()
    assert Board(BoardConfig()).can_tick()


def test_estop_empties_the_buffer_and_frames_due_after_the_clear_never_apply() -> None:
    board = make_board()
    for k in range(1, 51):  # 10 ms apart, head yaw to 0.5 rad at 0.5 s
        board.handle(_frame(k * 10_000, 0.01 * k), k)
    while board.now_us < 100_000:  # a realtime board's clock: frames to 0.5 s wait in the buffer
        board.tick()
    before = board.last_applied_seq
    assert 0 < before < 50 and len(board.buffer) > 0
    assert isinstance(board.handle(Estop(), 61)[0], Ack)
    assert len(board.buffer) == 0
    assert isinstance(board.handle(EstopClear(), 62)[0], Ack)  # at once: most frames were due after the clear
    board.handle(Advance(600_000), 63)
    run(board)
    assert board.now_us == 600_000
    tel = board.telemetry()
    assert tel.last_applied_seq == before and tel.buffer_fill == 0
    assert board.desired[HEAD_YAW] < 0.2  # never went on to the 0.5 rad of the dropped frames


def test_a_sparse_keyframe_interpolates_from_its_arrival() -> None:
    board = make_board()
    board.handle(Config(ConfigKey.WATCHDOG_MS, 10_000), 1)  # no hold during the long ADVANCE
    board.handle(_frame(20_000, 0.1), 2)
    board.handle(Advance(500_000), 3)
    run(board)
    assert board.now_us == 500_000 and board.last_applied_seq == 2
    # sparse: the last keyframe (0.02 s) is far older than 50 ms: the segment starts at arrival (0.5 s)
    board.handle(_frame(700_000, 0.3), 4)
    board.handle(Advance(600_000), 5)
    run(board)
    t = board.now_us - board.tick_us  # the last tick's time
    from_arrival = 0.1 + 0.2 * (t - 500_000) / 200_000
    from_keyframe = 0.1 + 0.2 * (t - 20_000) / 680_000
    assert abs(board.desired[HEAD_YAW] - from_arrival) < 1e-6, (board.desired[HEAD_YAW], from_arrival, from_keyframe)
    # dense: a frame arriving 20 ms after the last keyframe interpolates from that keyframe
    board.handle(Advance(720_000), 6)
    run(board)
    board.handle(_frame(800_000, 0.5), 7)
    board.handle(Advance(760_002), 8)
    run(board)
    t = board.now_us - board.tick_us
    assert abs(board.desired[HEAD_YAW] - (0.3 + 0.2 * (t - 700_000) / 100_000)) < 1e-6


def test_edge_and_level_fault_flags() -> None:
    board = make_board()
    board.on_link_error()
    first, second = board.telemetry(), board.telemetry()
    assert first.faults & FaultFlags.LINK_ERRORS and not second.faults & FaultFlags.LINK_ERRORS
    assert first.link_errors == second.link_errors == 1  # the counter stays
    board.handle(Estop(), 1)
    assert all(board.telemetry().faults & FaultFlags.ESTOP for _ in range(2))  # level
    board.handle(EstopClear(), 2)
    assert not board.telemetry().faults & FaultFlags.ESTOP


@pytest.mark.parametrize("key", list(ConfigKey))
def test_config_keys_table_is_what_the_board_accepts(key: ConfigKey) -> None:
    board = make_board()
    _, lo, hi, _ = CONFIG_RANGES[key]
    top = board.cfg.rate_hz if hi is None else hi
    for value, ok in ((lo, True), (lo - 1, False), (top, True), (top + 1, False)):
        if value > I32_MAX:
            continue
        (reply,) = board.handle(Config(key, value), 10)
        assert isinstance(reply, Ack if ok else Nack), (key, value, reply)
        if not ok:
            assert reply.reason is NackReason.BAD_VALUE


def test_message_table_gives_meanings_and_heartbeat_is_host_to_board() -> None:
    text = render()
    lines = text.split("\n")
    start = lines.index("## Message types") + 4
    rows = [[c.strip() for c in ln.strip("|").split("|")] for ln in lines[start:lines.index("", start)]]
    assert {r[1] for r in rows} == {t.name for t in MsgType} == {t.name for t in MEANING}
    for code, name, direction, meaning in rows:
        assert meaning.endswith(".") and ": '" not in meaning and f"{name.title()}(" not in meaning, (name, meaning)
    assert next(r for r in rows if r[1] == "HEARTBEAT")[2] == "host → board"
    assert "DEVELOPERS.md" not in text


def _decode_error(raw: bytes) -> DecodeError:
    (item,) = FrameDecoder().feed(raw)
    assert isinstance(item, DecodeError)
    return item


def test_only_a_well_formed_config_with_an_unknown_key_is_answerable() -> None:
    item = _decode_error(encode_raw_frame(MsgType.CONFIG, 7, struct.pack("<Bi", 9, -5)))
    frame = answerable(item)
    assert isinstance(frame, Frame) and frame.seq == 7 and frame.msg == Config(9, -5)  # type: ignore[arg-type]
    board = make_board()
    (nack,) = board.handle(frame.msg, frame.seq)
    assert isinstance(nack, Nack) and (nack.ack_seq, nack.msg_type, nack.reason) == (7, MsgType.CONFIG,
                                                                                     NackReason.BAD_VALUE)
    for raw in (encode_raw_frame(MsgType.CONFIG, 7, struct.pack("<Bi", 9, 1) + b"\x00"),  # wrong length
                encode_raw_frame(MsgType.SCREEN, 7, b"\x09\x00" + bytes(12)),  # another type's bad enum
                encode_raw_frame(MsgType.HEARTBEAT, 7, bytes(9))):  # not a CONFIG at all
        bad = _decode_error(raw)
        assert answerable(bad) is bad
    can = DecodeError(DecodeErrorKind.PAYLOAD, "CAN PAYLOAD: ...", bytes(14))  # CAN data bytes, not a COBS block
    assert answerable(can) is can


def test_board_help_and_the_wire_page_point_to_docs_pages() -> None:
    """``ghostshell board --help`` (the board's parser) and docs/concepts/wire.md send a reader to docs pages,
    not to DEVELOPERS.md or to source files."""
    import re
    from pathlib import Path

    from firmware_sim.cli import build_parser

    help_text = " ".join(build_parser().format_help().split())
    assert "docs/wire-protocol.md" in help_text and "DEVELOPERS.md" not in help_text
    assert not re.search(r"(?<![\w/-])(protocol|firmware_sim|host)\.[a-z_]+", help_text), help_text
    page = (Path(__file__).resolve().parents[2] / "docs" / "concepts" / "wire.md").read_text(encoding="utf-8")
    prose = re.sub(r"```.*?```", "", page, flags=re.S)
    assert "DEVELOPERS.md" not in prose and not re.search(r"`[\w/]+\.py`", prose)
    assert "../wire-protocol.md#refusals" in prose and "../wire-protocol.md#hashes" in prose
