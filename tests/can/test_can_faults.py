"""Fault injection on the board's CAN transport (python-can virtual bus, in-process, no board loop).

Both directions go through seeded per-frame injectors (``install_faults``); time is passed in, so
nothing waits. Checked: a bit flip in any frame never surfaces a message other than one sent (the
CAN layouts' CRC-16 drops it and it is counted), every lost message is a sequence gap, and the
injectors count what they did.
"""

from __future__ import annotations

import can
import pytest

from firmware_sim.transports.can import BusBoardTransport
from firmware_sim.transports.faulty import install_faults
from protocol.can import CanDecoder, CanFrame, CanItem, encode_fixed
from protocol.codec import quantize_message
from protocol.faults import FaultSpec, GapDetector
from protocol.framing import Frame
from protocol.linkspec import parse_link_spec
from protocol.messages import MsgType
from protocol.testing.samples import servo_frame_12, telemetry_12

SPEC = FaultSpec.parse("drop=0.05,corrupt=0.2,dup=0.05,reorder=0.05")
N = 300


def _bus_pair(channel: str) -> tuple[can.BusABC, BusBoardTransport]:
    host = can.Bus(interface="virtual", channel=channel)
    board = BusBoardTransport(parse_link_spec(f"can:virtual:{channel}"),
                              bus=can.Bus(interface="virtual", channel=channel))
    return host, board


def test_host_to_board_faults_never_surface_a_wrong_servo_frame(virtual_channel: str) -> None:
    host, board = _bus_pair(virtual_channel)
    try:
        rx, _tx = install_faults(board, SPEC, seed=11)
        sent = {}
        got: list[Frame] = []
        errors = 0
        now = 0.0
        for seq in range(N):
            msg = servo_frame_12(1_000_000 + 10_000 * seq)
            sent[seq] = quantize_message(msg)
            for f in encode_fixed(msg, seq, 1):
                host.send(can.Message(arbitration_id=f.arbitration_id, data=f.data, is_extended_id=False))
            now += 0.01
            for it in board.receive(now):
                if isinstance(it, Frame):
                    got.append(it)
                else:
                    errors += 1
        got += [it for it in board.receive(now + 1.0, read=False) if isinstance(it, Frame)]  # a held frame
        assert rx.injected["corrupt"] > 10 and rx.injected["drop"] > 5 and rx.injected["dup"] > 0
        assert got and all(it.msg == sent[it.seq] for it in got), "a corrupted SERVO_FRAME surfaced"
        assert board.decoder.errors  # CRC / incomplete / mixed, each counted
        assert errors == board.decoder.error_count
        gaps = GapDetector(window=65536, first=0)
        for it in got:
            gaps.feed(it.seq)
        seen = {it.seq for it in got}
        assert gaps.lost == len([q for q in range(max(seen)) if q not in seen])
        assert gaps.lost > 0
    finally:
        board.close()
        host.shutdown()


def test_board_to_host_faults_are_per_frame_and_caught(virtual_channel: str) -> None:
    host, board = _bus_pair(virtual_channel)
    try:
        _rx, tx = install_faults(board, SPEC, seed=12)
        clean = CanDecoder(1, "host")
        expected = {}
        now = 0.0
        for seq in range(N):
            msg = telemetry_12(2_000_000 + 20_000 * seq)
            for f in encode_fixed(msg, seq, 1, sender="board"):
                for it in clean.feed(f):
                    assert isinstance(it, CanItem)
                    expected[seq] = it.msg
            board.queue(msg, seq, now)
            now += 0.02
            board.flush(now)
        board.flush(now + 1.0)  # release a held frame
        dec = CanDecoder(1, "host")
        got = []
        while (m := host.recv(timeout=0)) is not None:
            for it in dec.feed(CanFrame(m.arbitration_id, bytes(m.data))):
                if isinstance(it, CanItem):
                    got.append(it)
        assert tx.units_in == 17 * N and tx.injected["corrupt"] > 100
        assert got and all(it.msg_type is MsgType.TELEMETRY and it.msg == expected[it.seq] for it in got)
        assert dec.errors and len({it.seq for it in got}) < N  # some reports lost, every one counted
    finally:
        board.close()
        host.shutdown()


def test_faults_refuse_a_link_that_is_neither_serial_nor_can() -> None:
    class Odd:
        pass

    with pytest.raises(ValueError, match="serial or CAN"):
        install_faults(Odd(), SPEC, 0)  # type: ignore[arg-type]
