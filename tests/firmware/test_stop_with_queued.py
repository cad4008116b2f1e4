"""A lockstep board stopped while received messages still wait in its inbox (logged as received, not
yet due) counts them: their sequence numbers feed the gap counter and bad frames the link errors, so
the board's ``seq_gaps`` agrees with its frame log. The kind of failure this keeps away: a CI run of
task 9 under faults whose last frame, a reordered one filling a gap, was logged but not counted (the
board said 47 gaps, its log 46)."""

from __future__ import annotations

from firmware_sim.board import Board
from firmware_sim.config import BoardConfig
from firmware_sim.server import BoardServer
from firmware_sim.transports.serial import SerialBoardTransport
from protocol.codec import SCHEMA_HASH
from protocol.framing import DecodeError, DecodeErrorKind, Frame
from protocol.messages import PROTOCOL_VERSION, Heartbeat, Hello, MsgType, Telemetry


def test_queued_messages_are_counted_when_a_lockstep_board_stops() -> None:
    transport = SerialBoardTransport("pty")
    board = Board(BoardConfig(lockstep=True))
    server = BoardServer(board, transport)
    try:
        board.handle(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 0), 0)
        board.handle(Heartbeat(0), 1)
        board.handle(Heartbeat(0), 3)  # 2 is missing
        assert board.rx_gaps.lost == 1
        late = Frame(2, MsgType.HEARTBEAT, Heartbeat(0), b"")  # reordered: arrives last, fills the gap
        after = Frame(5, MsgType.HEARTBEAT, Heartbeat(0), b"")  # 4 lost on the way
        own = Frame(6, MsgType.TELEMETRY, board.telemetry(), b"")  # a message the board sends: not link traffic
        bad = DecodeError(DecodeErrorKind.CRC, "CRC mismatch", b"\x00")
        server.inbox.extend([after, late, own, bad])
        errors = board.link_errors
        server.stop()
        server.serve()  # stopped: handles nothing, counts the queue
        assert not server.inbox
        assert board.rx_gaps.lost == 1 and board.rx_gaps.late == 1  # 4 lost; 2 arrived late
        assert board.link_errors == errors + 1
        assert board.rx_gaps.received == 5, "the board's own TELEMETRY was counted as link traffic"
        assert isinstance(own.msg, Telemetry)
    finally:
        transport.close()
