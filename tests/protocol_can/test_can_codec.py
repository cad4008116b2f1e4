"""CAN layouts: round trips through our codec, the DBC (cantools) both ways, reassembly rules."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import cantools
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol import messages as m
from protocol.can import CanDecodeError, CanDecoder, CanErrorKind, CanFrame, CanItem, encode_bulk, encode_fixed, is_fixed
from protocol.can.codec import Sender, fixed_crc, fixed_layout_for, message_to_raw
from protocol.can.ids import FunctionCode, cob_id, split_id
from protocol.can.layouts import CRC_SIGNAL, FIXED_LAYOUTS, unwrap_seq
from protocol.can.make_dbc import DbcRobot, dbc_text
from protocol.codec import PayloadError, msg_type_of, quantize_message
from protocol.messages import MsgType
from protocol.testing.samples import SAMPLES

COCO_DIR = Path(__file__).resolve().parents[2] / "robots" / "coco"  # CoCo's checked-in DBCs
COCO = DbcRobot("coco", "CoCo", 12)
DBC = {fd: cantools.database.load_file(str(COCO_DIR / ("coco_fd.dbc" if fd else "coco.dbc"))) for fd in (False, True)}

BOARD_BOUND = [MsgType.SERVO_FRAME, MsgType.TIME_SYNC_REQUEST, MsgType.FLUSH, MsgType.ADVANCE, MsgType.ESTOP, MsgType.ESTOP_CLEAR, MsgType.HEARTBEAT]
HOST_BOUND = [MsgType.TIME_SYNC_REPLY, MsgType.ACK, MsgType.TELEMETRY, MsgType.HEARTBEAT]


def _nack0() -> m.Nack:
    return m.Nack(8, MsgType.SERVO_FRAME, m.NackReason.LATE, "")


def _same(a: object, b: object) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return (math.isnan(a) and math.isnan(b)) or a == b
    if isinstance(a, tuple) and isinstance(b, tuple):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return a == b


def _roundtrip(msg: m.Message, receiver: str, fd: bool, seq: int = 1234, node: int = 1) -> CanItem:
    sender = Sender.BOARD if receiver == "host" else Sender.HOST
    frames = encode_fixed(msg, seq, node, fd, sender)
    dec = CanDecoder(node, receiver)
    dec.last_seq = seq - 5
    items = [i for f in frames for i in dec.feed(f)]
    assert len(items) == 1 and isinstance(items[0], CanItem), items
    assert items[0].seq == seq
    return items[0]


@pytest.mark.parametrize("fd", [False, True])
@pytest.mark.parametrize("t", BOARD_BOUND)
def test_board_bound_roundtrip(t: MsgType, fd: bool) -> None:
    item = _roundtrip(SAMPLES[t], "board", fd)
    assert _same(item.msg, quantize_message(SAMPLES[t]))


@pytest.mark.parametrize("fd", [False, True])
@pytest.mark.parametrize("t", HOST_BOUND)
def test_host_bound_roundtrip(t: MsgType, fd: bool) -> None:
    item = _roundtrip(SAMPLES[t], "host", fd)
    assert _same(item.msg, quantize_message(SAMPLES[t]))
    nack = _roundtrip(_nack0(), "host", fd).msg
    assert nack == _nack0()


def test_classic_frame_counts_and_ids() -> None:
    frames = encode_fixed(SAMPLES[MsgType.SERVO_FRAME], 7, 2)
    assert len(frames) == 6 and all(f.arbitration_id == 0x082 and len(f.data) == 8 for f in frames)
    fd_frames = encode_fixed(SAMPLES[MsgType.SERVO_FRAME], 7, 2, fd=True)
    assert len(fd_frames) == 1 and fd_frames[0].is_fd and len(fd_frames[0].data) == 48
    assert len(encode_fixed(SAMPLES[MsgType.TELEMETRY], 7, 2, sender=Sender.BOARD)) == 17
    assert len(encode_fixed(SAMPLES[MsgType.TELEMETRY], 7, 2, fd=True, sender=Sender.BOARD)) == 2


def test_priority_order() -> None:
    # ESTOP of any node beats everything of every node; servo and time sync beat telemetry; bulk last
    estop_max = max(cob_id(FunctionCode.ESTOP, n) for n in range(1, 128))
    for fn in FunctionCode:
        if fn is not FunctionCode.ESTOP:
            assert cob_id(fn, 1) > estop_max
    assert cob_id(FunctionCode.TIME_SYNC_REPLY, 127) < cob_id(FunctionCode.TELEMETRY, 1)
    assert cob_id(FunctionCode.TELEMETRY, 127) < cob_id(FunctionCode.BULK_TO_BOARD, 1)
    assert cob_id(FunctionCode.ESTOP, 0) == 0
    assert split_id(0x7FF) == (None, 0x7F)


def test_which_path() -> None:
    assert is_fixed(SAMPLES[MsgType.SERVO_FRAME]) and is_fixed(_nack0())
    for t in (MsgType.HELLO, MsgType.CAPS, MsgType.CONFIG, MsgType.SCREEN, MsgType.SPEAKER, MsgType.SIM_STATE, MsgType.NACK, MsgType.CAMERA_CHUNK):
        assert not is_fixed(SAMPLES[t])
        dec = CanDecoder(1, "host")
        item = dec.feed_bulk(encode_bulk(SAMPLES[t], 40000))
        assert isinstance(item, CanItem) and item.seq == 40000 and item.msg == quantize_message(SAMPLES[t])
    with pytest.raises(PayloadError):
        encode_fixed(SAMPLES[MsgType.NACK], 1, 1)
    with pytest.raises(PayloadError):
        encode_fixed(SAMPLES[MsgType.HELLO], 1, 1)


def test_invalid_messages_refused() -> None:
    with pytest.raises(PayloadError):
        encode_fixed(m.ServoFrame(0, 0x1000, (0.0,)), 1, 1)  # servo 13: not on CAN
    with pytest.raises(PayloadError):
        encode_fixed(m.ServoFrame(0, 0x3, (0.0,)), 1, 1)
    with pytest.raises(PayloadError):
        encode_fixed(m.ServoFrame(0, 0x1, (math.nan,)), 1, 1)
    with pytest.raises(ValueError):
        encode_fixed(m.Estop(), 1, 128)


def test_partial_frame_is_never_applied() -> None:
    frames = encode_fixed(SAMPLES[MsgType.SERVO_FRAME], 100, 1)
    later = encode_fixed(m.ServoFrame(5, 0xFFF, (0.5,) * 12), 101, 1)
    dec = CanDecoder(1, "board")
    out = [i for f in frames[:3] + later for i in dec.feed(f)]  # parts 3 and 4 of seq 100 lost
    msgs = [i for i in out if isinstance(i, CanItem)]
    assert [i.seq for i in msgs] == [101] and msgs[0].msg.targets == (0.5,) * 12  # type: ignore[union-attr]
    assert dec.errors[CanErrorKind.INCOMPLETE] == 1


def test_mixed_parts_are_dropped() -> None:
    a = encode_fixed(m.ServoFrame(5, 0xFFF, (0.1,) * 12), 100, 1)
    other = encode_fixed(m.ServoFrame(5, 0xFFF, (0.2,) * 12), 100, 1)  # same sequence, other content
    dec = CanDecoder(1, "board")
    out = [i for f in [a[0], a[1], other[1], a[2], a[3], a[4], a[5]] for i in dec.feed(f)]
    assert not any(isinstance(i, CanItem) for i in out)
    assert dec.errors[CanErrorKind.MIXED] == 1
    # a part of the same seq in the other frame format is mixed too
    b = encode_fixed(m.ServoFrame(5, 0xFFF, (0.1,) * 12), 100, 1, fd=True)[0]
    dec2 = CanDecoder(1, "board")
    assert dec2.feed(a[0]) == [] and dec2.feed(a[1]) == []
    out2 = dec2.feed(b)
    assert dec2.errors[CanErrorKind.MIXED] == 1 and isinstance(out2[-1], CanItem)  # the FD frame itself is whole


def test_a_part_received_twice_is_double_reception_not_an_error() -> None:
    # CAN's double reception: a retransmitted frame reaches a receiver twice (same data)
    a = encode_fixed(m.ServoFrame(5, 0xFFF, (0.1,) * 12), 100, 1)
    dec = CanDecoder(1, "board")
    out = [i for f in [a[0], a[1], a[1], a[2], a[3], a[4], a[5], a[5]] for i in dec.feed(f)]
    assert [i.seq for i in out if isinstance(i, CanItem)] == [100]
    assert dec.error_count == 0 and dec.duplicates == 2 and dec.pending_parts() == 0
    # a single-frame message received twice surfaces once
    ack = encode_fixed(m.Ack(7, MsgType.FLUSH), 200, 1, sender=Sender.BOARD)
    assert len(ack) == 1
    host = CanDecoder(1, "host")
    assert [len(host.feed(ack[0])), len(host.feed(ack[0]))] == [1, 0] and host.duplicates == 1


def test_parts_swapped_at_a_message_boundary_still_complete_both() -> None:
    a = encode_fixed(m.ServoFrame(5, 0xFFF, (0.1,) * 12), 100, 1)
    b = encode_fixed(m.ServoFrame(15, 0xFFF, (0.2,) * 12), 101, 1)
    dec = CanDecoder(1, "board")
    order = a[:5] + [b[0], a[5]] + b[1:]  # the last part of 100 arrives after the first of 101
    out = [i for f in order for i in dec.feed(f)]
    assert [i.seq for i in out if isinstance(i, CanItem)] == [100, 101] and dec.error_count == 0


def test_a_third_sequence_or_a_newer_complete_message_drops_the_incomplete_one() -> None:
    msgs = [encode_fixed(m.ServoFrame(5 + k, 0xFFF, (0.1,) * 12), 100 + k, 1) for k in range(3)]
    dec = CanDecoder(1, "board")
    out = [i for f in [msgs[0][0], msgs[1][0], msgs[2][0]] for i in dec.feed(f)]
    assert [i.kind for i in out if isinstance(i, CanDecodeError)] == [CanErrorKind.INCOMPLETE]  # 100 evicted
    out = [i for f in msgs[2][1:] for i in dec.feed(f)]  # 102 completes: 101 can no longer
    assert [i.seq for i in out if isinstance(i, CanItem)] == [102]
    assert dec.errors[CanErrorKind.INCOMPLETE] == 2 and dec.pending_parts() == 0


def test_other_nodes_and_directions_are_ignored() -> None:
    dec = CanDecoder(1, "board")
    for f in encode_fixed(SAMPLES[MsgType.SERVO_FRAME], 1, 2):
        assert dec.feed(f) == []
    for f in encode_fixed(SAMPLES[MsgType.TELEMETRY], 1, 1, sender=Sender.BOARD):
        assert dec.feed(f) == []
    assert dec.foreign == 23 and dec.error_count == 0  # 6 servo parts + 17 telemetry parts
    # broadcast ESTOP reaches every node, also with no data at all (cansend vcan0 000#)
    for node in (1, 2):
        items = CanDecoder(node, "board").feed(CanFrame(0x000, b""))
        assert isinstance(items[0], CanItem) and items[0].msg_type is MsgType.ESTOP


def test_seq_unwrap() -> None:
    assert unwrap_seq(5, 0xFFFE) == (0xFFFE + 7) & 0xFFFF
    assert unwrap_seq(2040, 3) == (3 - 11) & 0xFFFF
    assert unwrap_seq(100, 100) == 100


frames_st = st.builds(
    CanFrame,
    arbitration_id=st.one_of(st.integers(0, 0x7FF), st.integers(0, 0x1FFFFFFF)),
    data=st.binary(max_size=64),
    is_fd=st.booleans(),
    is_extended_id=st.booleans(),
    is_remote=st.booleans(),
)


@settings(max_examples=300, deadline=None)
@given(st.lists(frames_st, max_size=40), st.sampled_from(["board", "host"]))
def test_decoder_never_raises_and_stays_bounded(frames: list[CanFrame], receiver: str) -> None:
    dec = CanDecoder(1, receiver)
    for f in frames:
        dec.feed(f)
        assert dec.pending_parts() <= 17 * 2
    dec.feed_bulk(b"\xff\x00")


# --- the DBC ----------------------------------------------------------------------------------


@pytest.mark.parametrize("fd", [False, True])
def test_checked_in_dbc_is_generated(fd: bool) -> None:
    assert (COCO_DIR / ("coco_fd.dbc" if fd else "coco.dbc")).read_text() == dbc_text(fd, robot=COCO)


def _fixed_samples() -> list[tuple[m.Message, str]]:
    out: list[tuple[m.Message, str]] = [(SAMPLES[t], Sender.HOST) for t in BOARD_BOUND]
    out += [(SAMPLES[t], Sender.BOARD) for t in HOST_BOUND] + [(_nack0(), Sender.BOARD)]
    return out


@pytest.mark.parametrize("fd", [False, True])
def test_our_frames_decode_with_cantools(fd: bool) -> None:
    db = DBC[fd]
    for msg, sender in _fixed_samples():
        layout = fixed_layout_for(msg_type_of(msg), fd, sender)
        raw = message_to_raw(msg)
        if layout.has_crc:
            raw[CRC_SIGNAL] = fixed_crc(layout, 1234, raw)
        for k, f in enumerate(encode_fixed(msg, 1234, 1, fd, sender)):
            dm = db.get_message_by_frame_id(f.arbitration_id)
            assert dm.is_fd == fd and dm.length == len(f.data)
            sig = dm.decode(f.data, decode_choices=False, scaling=False)
            assert sig["part"] == k and sig["seq"] == 1234 % 2048
            mine = {p.spec.name: raw[p.spec.name] for p in layout.signals if p.part == k}
            assert {n: v for n, v in sig.items() if n not in ("part", "seq")} == mine
            phys = dm.decode(f.data, decode_choices=False)
            for p in layout.signals:
                if p.part == k:
                    assert phys[p.spec.name] == pytest.approx(raw[p.spec.name] * p.spec.scale)


@pytest.mark.parametrize("fd", [False, True])
def test_cantools_frames_decode_with_ours(fd: bool) -> None:
    db = DBC[fd]
    for msg, sender in _fixed_samples():
        layout = fixed_layout_for(msg_type_of(msg), fd, sender)
        raw = message_to_raw(msg)
        if layout.has_crc:  # a DBC user computes the CRC as the DBC comment says (fixed_crc)
            raw[CRC_SIGNAL] = fixed_crc(layout, 77, raw)
        dm = db.get_message_by_frame_id(cob_id(layout.fn, 1))
        dec = CanDecoder(1, "host" if sender == Sender.BOARD else "board")
        items = []
        for k in range(layout.parts):
            sig = {"part": k, "seq": 77} | {p.spec.name: raw[p.spec.name] for p in layout.signals if p.part == k}
            data = dm.encode(sig, scaling=False, strict=True)
            items += dec.feed(CanFrame(dm.frame_id, data, is_fd=fd))
        assert len(items) == 1 and isinstance(items[0], CanItem) and items[0].seq == 77
        assert _same(items[0].msg, quantize_message(msg)) or msg_type_of(msg) is MsgType.TELEMETRY
        if msg_type_of(msg) is MsgType.TELEMETRY:  # CAN telemetry always carries 12 servos
            assert _same(items[0].msg, _roundtrip(msg, "host", fd).msg)


def test_every_fixed_layout_in_dbc() -> None:
    for (fn, fd), layout in FIXED_LAYOUTS.items():
        dm = DBC[fd].get_message_by_frame_id(cob_id(fn, 2))
        assert dm.length == layout.length


@pytest.mark.parametrize("fd", [False, True])
def test_servo_frame_crc_catches_every_single_bit_flip(fd: bool) -> None:
    """No single flipped data bit of a SERVO_FRAME (header, signals, CRC) surfaces a message other
    than the one sent: the 16-bit header alone cannot catch a flipped target bit, the CRC does."""
    sent = m.ServoFrame(123_456, 0xFFF, tuple(0.01 * (i + 1) for i in range(12)))
    frames = encode_fixed(sent, 300, 1, fd=fd)
    layout_bits = [(k, b) for k, f in enumerate(frames) for b in range(len(f.data) * 8)]
    crc_caught = 0
    for k, bit in layout_bits:
        data = bytearray(frames[k].data)
        data[bit // 8] ^= 1 << (bit % 8)
        bad = list(frames)
        bad[k] = dataclasses.replace(frames[k], data=bytes(data))
        dec = CanDecoder(1, "board")
        dec.last_seq = 300
        items = [i for f in bad for i in dec.feed(f)]
        msgs = [i for i in items if isinstance(i, CanItem)]
        # a flip in unused padding bits changes nothing the receiver reads; anything else is dropped
        assert all(i.seq == 300 and i.msg == quantize_message(sent) for i in msgs), (k, bit)
        crc_caught += dec.errors[CanErrorKind.CRC]
    assert crc_caught > 12 * 16  # every target bit at least


def test_an_11_bit_sequence_coming_round_again_is_a_new_message() -> None:
    """A rare message (FLUSH) whose 11-bit sequence recurs 2048 messages later is neither taken
    for a double reception of the old one nor merged into the old one's unfinished parts."""
    dec = CanDecoder(1, "board")
    flush = encode_fixed(m.Flush(1_000, 0xFFF), 100, 1)
    assert len(flush) == 2
    got = [i for f in flush for i in dec.feed(f)]
    stale = encode_fixed(m.Flush(2_000, 0xFFF), 101, 1)[0]  # part 0 only: its part 1 was lost
    got += dec.feed(stale)
    for seq in range(102, 2148):  # other traffic in between (heartbeats, 2 parts each)
        got += [i for f in encode_fixed(m.Heartbeat(seq), seq, 1) for i in dec.feed(f)]
    again = encode_fixed(m.Flush(3_000, 0xFFF), 2148, 1)  # same 11-bit sequence as the first FLUSH
    later = encode_fixed(m.Flush(4_000, 0xFFF), 2149, 1)  # same 11-bit sequence as the stale one
    got += [i for f in again + later for i in dec.feed(f)]
    flushes = [(i.seq, i.msg.from_us) for i in got if isinstance(i, CanItem) and i.msg_type is MsgType.FLUSH]
    assert flushes == [(100, 1_000), (2148, 3_000), (2149, 4_000)]
    assert dec.errors[CanErrorKind.INCOMPLETE] == 1 and dec.errors[CanErrorKind.MIXED] == 0
    assert dec.duplicates == 0

