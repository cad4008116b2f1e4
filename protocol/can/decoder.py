"""Receiver side of the CAN protocol: frames in, whole messages out; never raises.

``CanDecoder(node, receiver="board"|"host").feed(frame) -> list[CanItem | CanDecodeError]``
takes any frame a bus delivers (any identifier, length, FD flag, remote or extended). Frames
that are not addressed to this receiver (another node, the other direction, bulk identifiers
that the ISO-TP layer consumes) are ignored and counted in ``foreign``. Fixed-layout messages are
reassembled from their parts (:mod:`protocol.can.layouts`): a message is surfaced only when
every part with the same sequence has arrived, in any order. A part received twice with the same
data, or a part of one of the last messages surfaced, is ignored and counted in ``duplicates`` (CAN's "double reception": a frame whose
acknowledgement was disturbed is retransmitted and reaches some receivers twice; ISO 11898-1
accepts it, so a receiver must be idempotent). A partial message (a later sequence of the same
function completes first, or a third one starts) or a mixed one (one part with two different
contents, FD and classic parts mixed) is **never** surfaced: it is dropped and counted
(``errors[INCOMPLETE]`` / ``errors[MIXED]``); so is a whole message whose ``crc16`` signal does
not match its parts (``errors[CRC]``). Two sequences per function may be assembled at once, so a
part that arrives after the first part of the next message (two frames swapped at a message
boundary) still completes its message. An assembly still unfinished ``STALE_FRAMES`` frames after
its first part is dropped (INCOMPLETE), and a surfaced sequence is forgotten as long after, so an
11-bit sequence that comes round again 2 048 messages later is a new message. State is bounded:
at most two assemblies and four surfaced sequences per function code. ``feed_bulk(sdu)`` decodes a reassembled ISO-TP unit.

``layouts`` is the robot's layout table (:func:`protocol.can.layouts.can_layouts`; default: the
:data:`~protocol.can.layouts.DEFAULT_SERVO_COUNT`-servo table); bulk units decode with its serial
schema. A fixed-layout frame of a message the table sends as bulk in that frame kind (classic
TELEMETRY above 27 servos) is dropped as ``errors[PAYLOAD]``.
"""

from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass, field
from enum import Enum
from functools import lru_cache

from protocol.can.codec import decode_bulk, fixed_crc, raw_to_message, unpack_part
from protocol.can.frame import CanFrame
from protocol.can.ids import BOARD_TO_HOST, BROADCAST_NODE, HOST_TO_BOARD, FunctionCode, check_node, split_id
from protocol.can.layouts import CRC_SIGNAL, SEQ_MASK, CanLayouts, FixedLayout, can_layouts, unwrap_seq
from protocol.codec import PayloadError, msg_type_of
from protocol.framing import DecodeError, DecodeErrorKind, Frame
from protocol.messages import Message, MsgType

__all__ = ["CanDecodeError", "CanDecoder", "CanErrorKind", "CanItem", "as_frame_items"]

_BULK = (FunctionCode.BULK_TO_BOARD, FunctionCode.BULK_TO_HOST)
MAX_ASSEMBLIES = 2  # sequences of one function code assembled at once
STALE_FRAMES = 512  # frames after which an unfinished assembly is dropped and a surfaced sequence forgotten


class CanErrorKind(Enum):
    EXTENDED_ID = "EXTENDED_ID"  # a 29-bit identifier (the protocol uses 11-bit ones)
    REMOTE = "REMOTE"  # a remote (RTR) frame
    LENGTH = "LENGTH"  # data shorter than the part's layout
    PART = "PART"  # part index beyond the message's parts
    PAYLOAD = "PAYLOAD"  # signal values the message cannot hold
    INCOMPLETE = "INCOMPLETE"  # a multi-part message dropped before all parts arrived
    MIXED = "MIXED"  # a part seen twice or parts of different frame kinds: dropped
    BULK = "BULK"  # an ISO-TP unit that does not decode
    CRC = "CRC"  # a whole message whose crc16 signal does not match its parts: dropped


@dataclass(frozen=True)
class CanItem:
    """One whole message: the 16-bit sequence (unwrapped for fixed frames), type, message."""

    seq: int
    msg_type: MsgType
    msg: Message
    frames: tuple[CanFrame, ...] = field(default=(), repr=False)
    bulk: bool = False


@dataclass(frozen=True)
class CanDecodeError:
    kind: CanErrorKind
    detail: str
    frame: CanFrame | None = None


@dataclass
class _Assembly:
    seq11: int
    fd: bool
    layout: FixedLayout
    raw: dict[str, int]
    parts: dict[int, CanFrame]
    born: int = 0  # the decoder's frame count when its first part arrived


@lru_cache(maxsize=None)
def _consumed_ids(node: int, receiver: str) -> frozenset[int]:
    """The 11-bit ids :meth:`CanDecoder.is_mine` accepts for ``node`` and ``receiver``: the node's own
    ids of the receiver's function codes (bulk excepted) and the broadcast ESTOP."""
    accept = HOST_TO_BOARD if receiver == "board" else BOARD_TO_HOST
    ids = {(int(fn) << 7) | node for fn in accept if fn not in _BULK}
    if FunctionCode.ESTOP in accept:
        ids.add((int(FunctionCode.ESTOP) << 7) | BROADCAST_NODE)
    return frozenset(ids)


class CanDecoder:
    """Reassembles fixed-layout messages for one receiver of one node; counts every problem."""

    def __init__(self, node: int, receiver: str = "board", layouts: CanLayouts | None = None) -> None:
        if receiver not in ("board", "host"):
            raise ValueError(f"receiver must be 'board' or 'host', got {receiver!r}")
        self.node = check_node(node)
        self.receiver = receiver
        self.layouts = can_layouts() if layouts is None else layouts
        self._accept = HOST_TO_BOARD if receiver == "board" else BOARD_TO_HOST
        self._mine = _consumed_ids(self.node, receiver)
        #: per function code, the assemblies in progress, oldest first (at most ``MAX_ASSEMBLIES``)
        self._assemblies: dict[FunctionCode, list[_Assembly]] = {}
        self.last_seq = 0  # 16-bit reference for unwrapping 11-bit sequences
        self.errors: Counter[CanErrorKind] = Counter()
        self.foreign = 0  # frames for other nodes / the other direction / bulk ids
        self.frames = 0
        self.duplicates = 0  # parts received again (ignored)
        #: per function code, the sequences surfaced last and the frame count then: a late copy of one
        #: of their parts (within ``STALE_FRAMES``) is a duplicate
        self._done: dict[FunctionCode, deque[tuple[int, int]]] = {}

    @property
    def error_count(self) -> int:
        return sum(self.errors.values())

    def is_mine(self, frame: CanFrame) -> bool:
        """True when ``frame`` is a fixed-layout frame this receiver consumes."""
        if frame.is_extended_id:
            return False
        fn, node = split_id(frame.arbitration_id)
        if fn is None or fn not in self._accept or fn in _BULK:
            return False
        if node == self.node:
            return True
        return node == BROADCAST_NODE and fn is FunctionCode.ESTOP

    def _error(self, kind: CanErrorKind, detail: str, frame: CanFrame | None) -> CanDecodeError:
        self.errors[kind] += 1
        return CanDecodeError(kind, detail, frame)

    def feed(self, frame: CanFrame) -> list[CanItem | CanDecodeError]:
        """Consume one frame; returns the messages it completes and the errors it causes."""
        try:
            return self._feed(frame)
        except Exception as e:  # defensive: a decoder bug must not take a receiver down
            return [self._error(CanErrorKind.PAYLOAD, f"internal decode error: {e!r}", frame)]

    def _feed(self, frame: CanFrame) -> list[CanItem | CanDecodeError]:
        self.frames += 1
        aid = int(frame.arbitration_id)
        if frame.is_extended_id or aid >> 11:  # 29-bit, or outside 0..0x7FF (a negative id shifts to -1)
            # another protocol's frame may share the bus: only count it as an error if it would
            # have been ours as a standard frame
            fn, node = split_id(aid)
            if fn is not None and node == self.node and fn in self._accept and 0 <= aid <= 0x7FF:
                return [self._error(CanErrorKind.EXTENDED_ID, f"29-bit identifier {aid:#x}", frame)]
            self.foreign += 1
            return []
        if aid not in self._mine:  # is_mine(frame) as one set lookup: every frame on the bus comes here
            self.foreign += 1
            return []
        fn, node = split_id(aid)
        assert fn is not None
        if frame.is_remote:
            return [self._error(CanErrorKind.REMOTE, f"remote frame on {aid:#05x}", frame)]
        data = bytes(frame.data)
        if fn is FunctionCode.ESTOP and len(data) < 2:
            # an ESTOP is honoured whatever its length (e.g. ``cansend vcan0 001#``); without a header
            # it gets a sequence 1024 behind the last one seen, which no request in flight can have
            seq = (self.last_seq - 1024) & 0xFFFF
            return [CanItem(seq, MsgType.ESTOP, raw_to_message(MsgType.ESTOP, {}, self.layouts), (frame,))]
        if len(data) < 2:
            return [self._error(CanErrorKind.LENGTH, f"{fn.name}: {len(data)} byte(s), no header", frame)]
        fd = bool(frame.is_fd)
        layout = self.layouts.layout(fn, fd)
        if layout is None:
            return [self._error(CanErrorKind.PAYLOAD, f"{fn.name}: no fixed layout for {self.layouts.servo_count} "
                                f"servos on {'CAN FD' if fd else 'classic CAN'} (it travels as ISO-TP)", frame)]
        header = int.from_bytes(data[:2], "little")
        part, seq11 = header & 0x1F, (header >> 5) & SEQ_MASK
        if part >= layout.parts:
            return [self._error(CanErrorKind.PART, f"{fn.name}: part {part} of {layout.parts}", frame)]
        if len(data) < layout.part_bytes[part]:
            return [
                self._error(
                    CanErrorKind.LENGTH,
                    f"{fn.name} part {part}: {len(data)} byte(s), needs {layout.part_bytes[part]}",
                    frame,
                )
            ]
        values = unpack_part(layout, part, data[: layout.part_bytes[part]])
        out: list[CanItem | CanDecodeError] = []
        done = self._done.setdefault(fn, deque(maxlen=MAX_ASSEMBLIES * 2))
        if any(q == seq11 and self.frames - at <= STALE_FRAMES for q, at in done):
            self.duplicates += 1  # double reception of a message already surfaced
            return []
        pending = self._assemblies.setdefault(fn, [])
        for old in [x for x in pending if self.frames - x.born > STALE_FRAMES]:
            # parts of one message travel back to back: one this old will not complete, and its
            # 11-bit sequence may come round again for a later message of this function
            pending.remove(old)
            self._incomplete(fn, old, out, frame)
        asm = next((x for x in pending if x.seq11 == seq11), None)
        if asm is not None and asm.fd != fd:
            pending.remove(asm)
            out.append(self._error(CanErrorKind.MIXED, f"{fn.name} seq {seq11}: classic and FD parts mixed", frame))
            asm = None
        if layout.parts == 1:
            self._drop_older(fn, seq11, out, frame)
            done.append((seq11, self.frames))
            return self._surface(layout, seq11, values, (frame,), out)
        if asm is None:
            while len(pending) >= MAX_ASSEMBLIES:  # a third sequence: the oldest cannot complete any more
                self._incomplete(fn, pending.pop(0), out, frame)
            asm = _Assembly(seq11, fd, layout, {}, {}, self.frames)
            pending.append(asm)
        seen = asm.parts.get(part)
        if seen is not None:
            if bytes(seen.data) == data:
                self.duplicates += 1  # double reception: same part, same content
                return out
            pending.remove(asm)
            out.append(self._error(CanErrorKind.MIXED, f"{fn.name} seq {seq11}: part {part} with two contents (dropped)", frame))
            return out
        asm.parts[part] = frame
        asm.raw.update(values)
        if len(asm.parts) == layout.parts:
            pending.remove(asm)
            self._drop_older(fn, seq11, out, frame)
            done.append((seq11, self.frames))
            frames = tuple(asm.parts[k] for k in range(layout.parts))
            return self._surface(layout, seq11, asm.raw, frames, out)
        return out

    def _incomplete(self, fn: FunctionCode, asm: _Assembly, out: list[CanItem | CanDecodeError], frame: CanFrame) -> None:
        out.append(self._error(CanErrorKind.INCOMPLETE,
                               f"{fn.name} seq {asm.seq11}: parts {sorted(asm.parts)} of {asm.layout.parts} (dropped)", frame))

    def _drop_older(self, fn: FunctionCode, seq11: int, out: list[CanItem | CanDecodeError], frame: CanFrame) -> None:
        """A message of ``fn`` completed: assemblies of earlier sequences will not complete any more."""
        pending = self._assemblies.get(fn, [])
        for old in [x for x in pending if 0 < (seq11 - x.seq11) & SEQ_MASK <= SEQ_MASK // 2]:
            pending.remove(old)
            self._incomplete(fn, old, out, frame)

    def _surface(
        self,
        layout: FixedLayout,
        seq11: int,
        raw: dict[str, int],
        frames: tuple[CanFrame, ...],
        out: list[CanItem | CanDecodeError],
    ) -> list[CanItem | CanDecodeError]:
        if layout.has_crc:
            want = fixed_crc(layout, seq11, raw)
            if raw.get(CRC_SIGNAL) != want:
                out.append(self._error(CanErrorKind.CRC, f"{layout.name} seq {seq11}: CRC {raw.get(CRC_SIGNAL, 0):#06x}, "
                                       f"parts give {want:#06x} (dropped)", frames[-1]))
                return out
        try:
            msg = raw_to_message(layout.msg_type, raw, self.layouts)
        except PayloadError as e:
            out.append(self._error(CanErrorKind.PAYLOAD, str(e), frames[-1]))
            return out
        seq = unwrap_seq(seq11, self.last_seq)
        self.last_seq = seq
        out.append(CanItem(seq, layout.msg_type, msg, frames))
        return out

    def feed_bulk(self, sdu: bytes) -> CanItem | CanDecodeError:
        """Decode one reassembled ISO-TP unit (its full sequence re-anchors the unwrapping)."""
        try:
            seq, msg = decode_bulk(sdu, self.layouts.schema)
        except PayloadError as e:
            return self._error(CanErrorKind.BULK, str(e), None)
        except Exception as e:  # defensive, as in feed()
            return self._error(CanErrorKind.BULK, f"internal decode error: {e!r}", None)
        self.last_seq = seq
        return CanItem(seq, msg_type_of(msg), msg, (), bulk=True)

    def pending_parts(self) -> int:
        """Parts held in incomplete assemblies (bounded by the layouts)."""
        return sum(len(a.parts) for p in self._assemblies.values() for a in p)


#: how each CAN decode error is reported on the link seam (the serial decoder's error kinds)
_SEAM_KIND = {
    CanErrorKind.LENGTH: DecodeErrorKind.LENGTH,
    CanErrorKind.PART: DecodeErrorKind.LENGTH,
    CanErrorKind.INCOMPLETE: DecodeErrorKind.LENGTH,
    CanErrorKind.MIXED: DecodeErrorKind.LENGTH,
    CanErrorKind.PAYLOAD: DecodeErrorKind.PAYLOAD,
    CanErrorKind.BULK: DecodeErrorKind.PAYLOAD,
    CanErrorKind.CRC: DecodeErrorKind.CRC,
    CanErrorKind.REMOTE: DecodeErrorKind.UNKNOWN_TYPE,
    CanErrorKind.EXTENDED_ID: DecodeErrorKind.UNKNOWN_TYPE,
}


def as_frame_items(items: list[CanItem | CanDecodeError]) -> list[Frame | DecodeError]:
    """CAN decoder output as the link seam's items: :class:`protocol.framing.Frame` (``raw`` = the
    frames' data concatenated) and :class:`protocol.framing.DecodeError` (the CAN error kind in ``detail``)."""
    out: list[Frame | DecodeError] = []
    for it in items:
        if isinstance(it, CanItem):
            out.append(Frame(it.seq, it.msg_type, it.msg, b"".join(f.data for f in it.frames)))
        else:
            raw = it.frame.data if it.frame is not None else b""
            out.append(DecodeError(_SEAM_KIND[it.kind], f"CAN {it.kind.value}: {it.detail}", raw))
    return out
