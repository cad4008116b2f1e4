"""CAN identifiers of the GhostShell protocol: 11-bit COB-IDs, function code high, node id low.

The layout follows CANopen's COB-ID (CiA 301): ``cob_id = function_code << 7 | node_id`` with a
4-bit function code (bits 10..7) and a 7-bit node id (bits 6..0, boards 1..127). On CAN the
lowest identifier wins arbitration, so the order of the function codes *is* the priority order:
ESTOP (and its broadcast form, id 0x000, which stops every board) beats every other frame of every
node, then servo frames and time sync, then control replies, telemetry and heartbeats, then bulk
(ISO-TP) transfers last.

====  ==================  ===========  ======================================================
code  function            direction    notes
====  ==================  ===========  ======================================================
0x0   ESTOP               host->board  0x000 = broadcast (every node); 0x001..0x07F one node
0x1   SERVO_FRAME         host->board  classic: 6 parts tied by sequence (the last ends with a CRC-16); FD: one frame
0x2   TIME_SYNC_REQUEST   host->board
0x3   TIME_SYNC_REPLY     board->host  classic: 3 parts; FD: one frame
0x4   FLUSH               host->board  classic: 2 parts
0x5   ADVANCE             host->board  lockstep only
0x6   ESTOP_CLEAR         host->board
0x7   ACK                 board->host
0x8   NACK                board->host  without detail text (a NACK with detail goes as bulk)
0x9   TELEMETRY           board->host  classic: 17 parts; FD: 2 parts
0xA   HEARTBEAT_HOST      host->board
0xB   HEARTBEAT_BOARD     board->host
0xC   BULK_TO_BOARD       host->board  ISO-TP (ISO 15765-2) data + flow control of the reverse
0xD   BULK_TO_HOST        board->host  ISO-TP
0xE   (spare)
0xF   (reserved: 0x7F0..0x7FF were not allowed in CAN 2.0A)
====  ==================  ===========  ======================================================

The bulk pair mirrors CANopen SDO addressing (0x600 + node to the server); one ISO-TP link per
node uses ``BULK_TO_BOARD`` for the host's data frames and the board's flow control, and
``BULK_TO_HOST`` the other way round.
"""

from __future__ import annotations

from enum import IntEnum

__all__ = [
    "BROADCAST_NODE",
    "ESTOP_BROADCAST_ID",
    "FunctionCode",
    "HOST_TO_BOARD",
    "BOARD_TO_HOST",
    "MAX_NODE",
    "cob_id",
    "split_id",
    "bulk_ids",
    "check_node",
]

BROADCAST_NODE = 0
MAX_NODE = 127


class FunctionCode(IntEnum):
    """High 4 bits of the 11-bit identifier; lower value = higher bus priority."""

    ESTOP = 0x0
    SERVO_FRAME = 0x1
    TIME_SYNC_REQUEST = 0x2
    TIME_SYNC_REPLY = 0x3
    FLUSH = 0x4
    ADVANCE = 0x5
    ESTOP_CLEAR = 0x6
    ACK = 0x7
    NACK = 0x8
    TELEMETRY = 0x9
    HEARTBEAT_HOST = 0xA
    HEARTBEAT_BOARD = 0xB
    BULK_TO_BOARD = 0xC
    BULK_TO_HOST = 0xD


HOST_TO_BOARD = frozenset(
    {
        FunctionCode.ESTOP,
        FunctionCode.SERVO_FRAME,
        FunctionCode.TIME_SYNC_REQUEST,
        FunctionCode.FLUSH,
        FunctionCode.ADVANCE,
        FunctionCode.ESTOP_CLEAR,
        FunctionCode.HEARTBEAT_HOST,
        FunctionCode.BULK_TO_BOARD,
    }
)
BOARD_TO_HOST = frozenset(set(FunctionCode) - HOST_TO_BOARD)

ESTOP_BROADCAST_ID = 0x000


def check_node(node: int) -> int:
    """``node`` as an int in 1..127 (``ValueError`` otherwise)."""
    n = int(node)
    if not 1 <= n <= MAX_NODE:
        raise ValueError(f"CAN node id must be 1..{MAX_NODE}, got {node!r}")
    return n


def cob_id(fn: FunctionCode, node: int) -> int:
    """11-bit identifier ``fn << 7 | node`` (node 0 only for the broadcast ESTOP)."""
    if node == BROADCAST_NODE and fn is FunctionCode.ESTOP:
        return ESTOP_BROADCAST_ID
    return (int(fn) << 7) | check_node(node)


_BY_CODE: dict[int, FunctionCode] = {int(f): f for f in FunctionCode}  # split_id runs for every received frame


def split_id(arbitration_id: int) -> tuple[FunctionCode | None, int]:
    """(function code or None if unassigned, node id) of an 11-bit identifier; never raises."""
    aid = int(arbitration_id) & 0x7FF
    return _BY_CODE.get(aid >> 7), aid & 0x7F


def bulk_ids(node: int) -> tuple[int, int]:
    """(host->board id, board->host id) of the node's ISO-TP link (normal 11-bit addressing)."""
    return cob_id(FunctionCode.BULK_TO_BOARD, node), cob_id(FunctionCode.BULK_TO_HOST, node)
