"""The C CAN engine (firmware_sim/c/core/can) and the Python one (protocol/can, firmware_sim/transports/can.py)
give the same frames, frame for frame.

For robots of 12, 16, 17, 28 and 32 servos (the layout table is generated per robot at build time from
protocol.can.layouts.can_layouts(N); classic TELEMETRY has no fixed layout above 27 servos and goes as ISO-TP),
classic and FD: hypothesis builds every fixed-layout message from the declaration (the codec equivalence test's
strategies) and both encoders give the same frames or both refuse; both decoders, fed the frames in any order,
surface the same message with the same sequence (or the same error kinds). ISO-TP: the C link and can-isotp (with
isotp_link.py's parameters) emit the same frames for the same units both ways. The board's transmit policy: the
same sends, received frames and refused writes give the same frames on the bus, in the same order.
The harness runs under ASan/UBSan.
"""

from __future__ import annotations

import random
from collections.abc import Iterator

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from firmware_sim.cfirmware.build import build
from firmware_sim.transports.can import CanBoardTransport
from protocol import codec as c
from protocol.can.codec import Sender, encode_fixed
from protocol.can.decoder import CanDecodeError, CanDecoder, CanItem
from protocol.can.frame import CanFrame
from protocol.can.ids import FunctionCode, cob_id
from protocol.can.isotp_link import IsoTpLink
from protocol.can.layouts import can_layouts
from protocol.codec import CAN_FIXED, PayloadError, schema_for
from protocol.linkspec import parse_link_spec
from protocol.messages import Ack, Caps, FaultFlags, Heartbeat, MsgType, Nack, NackReason, SimState, Telemetry, TimeSyncReply
from robots.loader import load_robot_dir
from support.gen_robot import write_chain_robot
from tests.cfirmware.conftest import CodecHarness
from tests.cfirmware.test_codec_equivalence import messages

SERVO_COUNTS = (12, 16, 17, 28, 32)
SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                           HealthCheck.function_scoped_fixture])


@pytest.fixture(scope="module", params=SERVO_COUNTS, ids=lambda n: f"{n}servos")
def can_harness(request, coco, tmp_path_factory) -> Iterator[tuple[int, CodecHarness]]:
    n: int = request.param
    robot = coco if n == coco.servo_count else load_robot_dir(write_chain_robot(tmp_path_factory.mktemp("robots"), n))
    assert robot.servo_count == n
    h = CodecHarness(build("can-harness", robot))
    yield n, h
    h.close()


def _text(f: CanFrame) -> str:
    return f"{f.arbitration_id:x}:{(1 if f.is_fd else 0) | (2 if f.is_extended_id else 0) | (4 if f.is_remote else 0)}:{f.data.hex()}"


def _frame(text: str) -> CanFrame:
    aid, flags, data = text.split(":")
    fl = int(flags)
    return CanFrame(int(aid, 16), bytes.fromhex(data), is_fd=bool(fl & 1), is_extended_id=bool(fl & 2), is_remote=bool(fl & 4))


def _frames(answer: str) -> list[str]:
    assert answer.startswith("="), answer
    return answer.split()[1:]


def _py_item(it: CanItem | CanDecodeError, schema: c.WireSchema) -> str:
    if isinstance(it, CanItem):
        return f"M:{int(it.msg_type)}:{it.seq}:{schema.encode_payload(it.msg).hex()}"
    return f"X:{it.kind.value}"


FIXED_TYPES = sorted(CAN_FIXED, key=int)


@SETTINGS
@given(data=st.data())
def test_fixed_frames_identical(can_harness, data) -> None:
    n, h = can_harness
    schema = schema_for(n)
    layouts = can_layouts(n)
    t = data.draw(st.sampled_from(FIXED_TYPES))
    msg = data.draw(messages(t, schema))
    payload = schema.encode_payload(msg)
    seq = data.draw(st.integers(0, 0xFFFF))
    node = data.draw(st.integers(1, 127))
    for fd in (False, True):
        for sender in (Sender.HOST, Sender.BOARD):
            try:
                py = [_text(f) for f in encode_fixed(msg, seq, node, fd, sender, layouts)]
            except PayloadError:
                py = None
            answer = h.ask(f"E {int(fd)} {int(sender == Sender.BOARD)} {seq} {node} {int(t)} {payload.hex()}")
            if py is None:
                assert answer.startswith("ERR"), (t.name, fd, answer)
                continue
            assert _frames(answer) == py, (t.name, fd, sender)
            # both receivers, the parts in any order: the same message, sequence and errors
            board_receives = t not in (MsgType.TIME_SYNC_REPLY, MsgType.ACK, MsgType.NACK, MsgType.TELEMETRY) and not (
                t is MsgType.HEARTBEAT and sender == Sender.BOARD)
            order = data.draw(st.permutations(py))
            dec = CanDecoder(node, "board" if board_receives else "host", layouts)
            assert h.ask(f"R {node} {int(board_receives)}") == "OK"
            for text in order:
                want = [_py_item(it, schema) for it in dec.feed(_frame(text))]
                aid, flags, hexdata = text.split(":")
                got = h.ask(f"D {aid} {flags} {hexdata}").split()[1:]
                assert got == want, (t.name, fd)


@SETTINGS
@given(data=st.data())
def test_decoders_agree_on_damaged_frames(can_harness, data) -> None:
    """Frames with flipped bits, cut short, another frame kind, extended or remote, duplicated and
    reordered: both decoders give the same items."""
    n, h = can_harness
    schema = schema_for(n)
    layouts = can_layouts(n)
    node = 5
    dec = CanDecoder(node, "board", layouts)
    assert h.ask(f"R {node} 1") == "OK"
    host_types = [t for t in FIXED_TYPES if t not in (MsgType.TIME_SYNC_REPLY, MsgType.ACK, MsgType.NACK, MsgType.TELEMETRY)]
    frames: list[CanFrame] = []
    for _ in range(data.draw(st.integers(1, 4))):
        t = data.draw(st.sampled_from(host_types))
        msg = data.draw(messages(t, schema))
        try:
            frames += encode_fixed(msg, data.draw(st.integers(0, 0xFFFF)), node, data.draw(st.booleans()), Sender.HOST, layouts)
        except PayloadError:
            continue
    rnd = random.Random(data.draw(st.integers(0, 2**32 - 1)))
    out: list[CanFrame] = []
    for f in frames:
        d = bytearray(f.data)
        r = rnd.random()
        if r < 0.1 and d:
            d[rnd.randrange(len(d))] ^= 1 << rnd.randrange(8)
        elif r < 0.15:
            d = d[: rnd.randrange(len(d) + 1)]
        out.append(CanFrame(f.arbitration_id, bytes(d), is_fd=f.is_fd if r > 0.02 else not f.is_fd,
                            is_extended_id=0.15 <= r < 0.17, is_remote=0.17 <= r < 0.19))
        if rnd.random() < 0.1:
            out.append(out[-1])
    rnd.shuffle(out)
    for f in out:
        want = [_py_item(it, schema) for it in dec.feed(f)]
        got = h.ask(f"D {f.arbitration_id:x} {_text(f).split(':')[1]} {f.data.hex()}").split()[1:]
        assert got == want


def _isotp_exchange(h: CodecHarness, sdu: bytes, fd: bool, fc: str | None) -> None:
    """One unit from C and from can-isotp to can-isotp receivers: the same frames (FF/SF, the FC, the CFs)."""
    host_rx: list[CanFrame] = []
    board_out: list[CanFrame] = []
    py_sender = IsoTpLink(rxid=0x601, txid=0x681, fd=fd, send=board_out.append)
    receiver = IsoTpLink(rxid=0x681, txid=0x601, fd=fd, send=host_rx.append)
    assert h.ask(f"I 601 681 {int(fd)}") == "OK"
    py_sender.send(sdu)
    py_sender.poll()
    assert h.ask(f"S {sdu.hex()}") == "OK"
    c_frames = h.ask("P 1000").split("|")[0].split()[1:]
    assert c_frames == [_text(f) for f in board_out]
    got_units: list[bytes] = []
    for f in board_out:
        receiver.feed(f)
        got_units += receiver.poll()
    if fd and len(sdu) <= 7:
        # can-isotp pads a 1..7-byte single frame to 64 bytes on FD but refuses such a frame without the escape
        # sequence on reception (no unit of the protocol is that short: a bulk unit is at least 5 bytes and every
        # message of <= 2 payload bytes is fixed); the frame itself is what both senders emit
        return
    if len(board_out) == 1 and not got_units:
        flow = host_rx[-1] if fc is None else _frame(fc)
        py_sender.feed(flow)
        board_out.clear()
        py_sender.poll()
        h.ask(f"T {flow.arbitration_id:x} {int(flow.is_fd)} {flow.data.hex()}")
        c_frames = h.ask("P 2000").split("|")[0].split()[1:]
        assert c_frames == [_text(f) for f in board_out]
        for f in board_out:
            receiver.feed(f)
            got_units += receiver.poll()
    if fc is None:
        assert got_units == [sdu]


@SETTINGS
@given(sdu=st.binary(min_size=1, max_size=260), fd=st.booleans())
def test_isotp_send_identical(can_harness, sdu, fd) -> None:
    _, h = can_harness
    _isotp_exchange(h, sdu, fd, None)


@SETTINGS
@given(sdu=st.binary(min_size=1, max_size=260), fd=st.booleans())
def test_isotp_receive_identical(can_harness, sdu, fd) -> None:
    """can-isotp sends, C receives: the same flow control, the same unit."""
    _, h = can_harness
    if fd and len(sdu) <= 7:
        sdu += b"\0" * (8 - len(sdu))  # see _isotp_exchange
    frames: list[CanFrame] = []
    fc_out: list[CanFrame] = []
    sender = IsoTpLink(rxid=0x681, txid=0x601, fd=fd, send=frames.append)
    py_rx = IsoTpLink(rxid=0x601, txid=0x681, fd=fd, send=fc_out.append)
    sender.send(sdu)
    sender.poll()
    assert h.ask(f"I 601 681 {int(fd)}") == "OK"
    c_units: list[str] = []
    c_out: list[str] = []
    py_units: list[bytes] = []
    for _ in range(3):
        batch, frames[:] = list(frames), []
        for f in batch:
            h.ask(f"T {f.arbitration_id:x} {int(f.is_fd)} {f.data.hex()}")
            ans = h.ask("P 1000")
            head, units, _ = ans.split("|")
            c_out += head.split()[1:]
            c_units += units.split()
            py_rx.feed(f)
            py_units += py_rx.poll()
        for f in fc_out:
            sender.feed(f)
        fc_out_copy = [_text(f) for f in fc_out]
        assert c_out == fc_out_copy
        fc_out.clear()
        c_out.clear()
        sender.poll()
    assert c_units == [u.hex() for u in py_units] == [sdu.hex()]


class _ListWire(CanBoardTransport):
    """The Python board's CAN transport over a list (its subclass hooks: what it reads, what the bus takes)."""

    def __init__(self, n: int, fd: bool) -> None:
        super().__init__(parse_link_spec(f"can:virtual:x?node=1{'&fd=1' if fd else ''}"), None, n)
        self.inbox: list[CanFrame] = []
        self.wire: list[CanFrame] = []
        self.refuse = 0

    def fileno(self) -> int | None:
        return None

    def _read_frames(self) -> list[CanFrame]:
        out, self.inbox = self.inbox, []
        return out

    def _write_frame(self, frame: CanFrame) -> bool | None:
        if self.refuse > 0:
            self.refuse -= 1
            return False
        self.wire.append(frame)
        return True


def _board_messages(n: int) -> list:
    tel = Telemetry(board_time_us=5_000_000, positions=(0.25,) * n, velocities=(-0.5,) * n, efforts=(0.125,) * n,
                    imu_rpy=(0.0, 0.01, -0.02), faults=FaultFlags(0), buffer_fill=3, last_applied_seq=9, late_count=0,
                    dropped_count=1, link_errors=2)
    return [
        (tel, True),
        (SimState(board_time_us=5_000_000, base_pos=(0.0, 0.0, 0.3), base_quat=(1.0, 0.0, 0.0, 0.0), objects=0, toppled=0), True),
        (Ack(ack_seq=12, msg_type=MsgType.ADVANCE), False),
        (Nack(ack_seq=13, msg_type=MsgType.SERVO_FRAME, reason=NackReason.LATE, detail="late by 3 ms"), False),
        (Nack(ack_seq=14, msg_type=MsgType.CONFIG, reason=NackReason.BAD_VALUE, detail="no such key"), False),
        (TimeSyncReply(t1_host_us=1, t2_board_us=2, t3_board_us=3), False),
        (Heartbeat(sender_time_us=77), False),
        (Caps(protocol_version=1, schema_hash=schema_for(n).hash, servo_count=n, control_rate_hz=500, buffer_depth=32,
              telemetry_rate_hz=50, board_time_us=0, lockstep=True, robot="chain", servo_table_hash=1), False),
    ]


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_board_transport_identical(can_harness, data) -> None:
    """The same sends, host frames and refused writes: the C board link and CanBoardTransport put the same
    frames on the bus in the same order (priority, periodic newest-wins, NACK trimming, ENOBUFS backoff)."""
    n, h = can_harness
    fd = data.draw(st.booleans())
    schema = schema_for(n)
    py = _ListWire(n, fd)
    assert h.ask(f"L 1 {int(fd)}") == "OK"
    seq = 0
    now_us = 0
    catalogue = _board_messages(n)
    host_hb = encode_fixed(Heartbeat(sender_time_us=1), 0, 1, fd, Sender.HOST, can_layouts(n))
    for _ in range(data.draw(st.integers(1, 25))):
        op = data.draw(st.sampled_from(["send", "send", "send", "host", "flush", "fc"]))
        if op == "send":
            msg, periodic = data.draw(st.sampled_from(catalogue))
            if py.queue(msg, seq, now_us / 1e6):
                seq = (seq + 1) & 0xFFFF
            assert h.ask(f"Q {int(periodic)} {now_us} {int(c.msg_type_of(msg))} {schema.encode_payload(msg).hex()}").startswith("=")
        elif op == "host":
            py.inbox += host_hb
            py.receive(now_us / 1e6)
            for f in host_hb:
                h.ask(f"K {now_us} {_text(f).replace(':', ' ')}")
            h.ask("N")
        elif op == "fc":  # the host's flow control for a board's First Frame
            fcf = CanFrame(cob_id(FunctionCode.BULK_TO_BOARD, 1), bytes([0x30, 0, 0]) + b"\xcc" * (61 if fd else 5), is_fd=fd)
            py.inbox.append(fcf)
            py.receive(now_us / 1e6)
            h.ask(f"K {now_us} {_text(fcf).replace(':', ' ')}")
            h.ask("N")
        else:
            refuse = data.draw(st.integers(0, 2))
            py.refuse = refuse
            before = len(py.wire)
            # past the backoff of a refused write (1 ms doubling), else 1 ms on: ISO-TP's 200 ms timers never run out
            now_us = max(now_us + 1000, int(py._retry_at * 1e6) + 1 if py._retry_at is not None else 0)
            py.flush(now_us / 1e6)
            got = _frames(h.ask(f"W {now_us} {refuse}"))
            assert got == [_text(f) for f in py.wire[before:]]
    g = h.ask("G").split()
    assert int(g[1]) == py.backlog
    assert int(g[6]) == seq


def test_isotp_timeouts_are_judged_at_arrival_in_c_as_in_python(can_harness) -> None:
    """gs_isotp.c and isotp_link.py judge N_Bs and N_Cr at a frame's arrival (``T ... AT_US``), not at the poll
    that reaches it: frames that came in time and were read 400-600 ms late complete the unit on both; the same
    frames arriving late time out on both (tests/protocol_can/test_isotp_arrival_time.py has the Python side alone)."""
    _, h = can_harness
    sdu = bytes(range(40))
    ms = 1_000_000
    now = [5_000 * ms]
    sent: list[CanFrame] = []
    frames: list[CanFrame] = []
    sender = IsoTpLink(rxid=0x681, txid=0x601, fd=False, send=frames.append)
    sender.send(sdu)
    sender.poll()
    sender.feed(CanFrame(0x681, bytes([0x30, 0, 0]) + b"\xcc" * 5))
    sender.poll()
    ff, cfs = frames[0], frames[1:]
    assert len(cfs) == 5
    for late in (False, True):
        assert h.ask("I 601 681 0") == "OK"
        t0 = 5_000_000 + (10_000_000 if late else 0)  # us; a new link each round
        now[0] = t0 * 1000
        py_rx = IsoTpLink(rxid=0x601, txid=0x681, fd=False, send=sent.append, clock=lambda: now[0])
        h.ask(f"T 601 0 {ff.data.hex()} {t0}")
        c_head = h.ask(f"P {t0}")
        py_rx.feed(ff, at_ns=t0 * 1000)
        py_rx.poll()
        arrive = t0 + (250_000 if late else 2_000)  # us: 2 ms after the flow control, or 250 ms (past N_Cr)
        for f in cfs:
            h.ask(f"T 601 0 {f.data.hex()} {arrive}")
            py_rx.feed(f, at_ns=arrive * 1000)
        read = t0 + 600_000  # the loop gets to them 600 ms after the First Frame
        now[0] = read * 1000
        head, units, counts = h.ask(f"P {read}").split("|")
        py_units = py_rx.poll()
        assert "30" in c_head  # the flow control
        c_errors = int(counts.split()[0])
        if late:
            assert units.split() == [] and py_units == []
            assert c_errors >= 1 and py_rx.errors >= 1
        else:
            assert units.split() == [sdu.hex()] and py_units == [sdu]
            assert c_errors == 0 and py_rx.errors == 0


def test_isotp_lockstep_board_clock_in_c_as_in_python(can_harness) -> None:
    """A lockstep board's N_Bs counts board time (``C BOARD_US``; isotp_link.py ``board_clock``), with the standard's
    1 000 ms of wall time as the backstop: the same flow-control timeouts on both, case by case."""
    _, h = can_harness
    ms = 1_000_000
    fc = CanFrame(0x601, bytes([0x30, 0, 0]) + b"\xcc" * 5)
    # (wall ms, board ms) from the First Frame to the flow control's arrival and the poll that reads it
    for wall_ms, board_ms, timed_out in ((600, 50, False), (10, 201, True), (999, 0, False), (1001, 0, True)):
        now, board = [7_000 * ms], [3_000 * ms]
        sent: list[CanFrame] = []
        py = IsoTpLink(rxid=0x601, txid=0x681, fd=False, send=sent.append, clock=lambda: now[0], board_clock=lambda: board[0])
        py.send(bytes(range(40)))
        py.poll()
        assert h.ask("I 601 681 0") == "OK" and h.ask(f"C {board[0] // 1000}") == "OK"
        assert h.ask(f"S {bytes(range(40)).hex()}") == "OK"
        h.ask(f"P {now[0] // 1000}")
        now[0] += wall_ms * ms
        board[0] += board_ms * ms
        assert h.ask(f"C {board[0] // 1000}") == "OK"
        h.ask(f"T 601 0 {fc.data.hex()} {now[0] // 1000}")
        py.feed(fc, at_ns=now[0])
        head, _, counts = h.ask(f"P {now[0] // 1000}").split("|")
        py.poll()
        c_fc_timeouts = int(counts.split()[1])
        assert c_fc_timeouts == py.flow_control_timeouts == int(timed_out), (wall_ms, board_ms)
        assert len(head.split()[1:]) == len(sent) - 1 == (0 if timed_out else 5), (wall_ms, board_ms)
