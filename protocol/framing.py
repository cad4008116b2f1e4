"""Serial framing for protocol version 1: COBS frames ended by a 0x00 delimiter.

Frame layout before COBS (all integers little-endian)::

    offset  size  field
    0       1     version   PROTOCOL_VERSION (1)
    1       1     type      MsgType
    2       2     seq       u16, one counter per direction, wraps
    4       1     length    payload length in bytes (0..255)
    5       n     payload   protocol.codec layout of the message type
    5+n     2     crc       CRC-16/X-25 over bytes 0 .. 5+n-1, little-endian

The whole block is COBS-encoded (``cobs`` package: no 0x00 inside, one code byte
of overhead per 254 bytes) and followed by a single 0x00. A receiver that loses
sync therefore resynchronises at the next 0x00: garbage on the line damages at
most the frame it touches. Empty frames (0x00 0x00) are ignored, so a sender may
write a lone 0x00 after opening a port to flush any partial bytes at the receiver.

CRC: crcmod's predefined ``'x-25'`` (CRC-16/IBM-SDLC: poly 0x1021 reflected,
init 0xFFFF, xorout 0xFFFF); check value for ``b"123456789"`` is ``0x906E``.

A version-1 12-servo SERVO_FRAME is 5 + 30 + 2 = 37 bytes, 39 on the wire.

The payload layouts of SERVO_FRAME, FLUSH and TELEMETRY depend on the robot's wire schema
(:class:`protocol.codec.WireSchema`, u16 or u32 servo mask): :func:`encode_frame` and
:class:`FrameDecoder` take the session's ``schema`` (default: the u16 schema, every robot of up
to 16 servos); the header, CRC and COBS are the same for every schema.
Future protocol versions must keep byte 0 as the version and the CRC at the
end so that a version mismatch is reported as ``VERSION`` rather than garbage.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import Enum

import crcmod.predefined
from cobs import cobs

from protocol.codec import WIRE_SCHEMA_16, MAX_PAYLOAD, PayloadError, WireSchema, msg_type_of
from protocol.fastcodec import FAST_ERRORS, fast_for
from protocol.messages import PROTOCOL_VERSION, Message, MsgType, ServoFrame, SimState, Telemetry

__all__ = [
    "CRC_CHECK",
    "CRC_NAME",
    "DecodeError",
    "DecodeErrorKind",
    "DEFAULT_MAX_FRAME_BYTES",
    "FRAME_DELIMITER",
    "Frame",
    "FrameDecoder",
    "HEADER_SIZE",
    "CRC_SIZE",
    "MAX_WIRE_FRAME",
    "WIRE_OVERHEAD",
    "crc16",
    "encode_frame",
    "encode_raw_frame",
    "frame_size",
]

#: the byte that ends every frame on the wire (COBS leaves no other 0x00 in it)
FRAME_DELIMITER = 0

CRC_NAME = "x-25"
#: CRC of b"123456789" for :data:`CRC_NAME` (the catalogue's check value).
CRC_CHECK = 0x906E
crc16 = crcmod.predefined.mkPredefinedCrcFun(CRC_NAME)

_HEADER = struct.Struct("<BBHB")
HEADER_SIZE = _HEADER.size  # 5
CRC_SIZE = 2
_CRC = struct.Struct("<H")

#: Wire bytes added to a payload of up to 247 bytes: header 5 + CRC 2 + COBS code byte 1 + delimiter 1.
WIRE_OVERHEAD = HEADER_SIZE + CRC_SIZE + 1 + 1

_MAX_RAW = HEADER_SIZE + MAX_PAYLOAD + CRC_SIZE  # 262
#: Longest possible valid frame on the wire, delimiter included.
MAX_WIRE_FRAME = _MAX_RAW + (_MAX_RAW // 254 + 1) + 1  # 266
DEFAULT_MAX_FRAME_BYTES = 512


class DecodeErrorKind(Enum):
    """Why a received frame was discarded."""

    COBS = "COBS"  # the bytes between delimiters are not valid COBS
    CRC = "CRC"  # checksum mismatch (line noise, truncation, merged garbage)
    LENGTH = "LENGTH"  # too short for a header + CRC, or length field != payload size
    VERSION = "VERSION"  # intact frame of another protocol version
    UNKNOWN_TYPE = "UNKNOWN_TYPE"  # intact frame with a message type this version lacks
    PAYLOAD = "PAYLOAD"  # intact frame whose payload does not decode (protocol.codec.PayloadError)
    OVERSIZE = "OVERSIZE"  # no delimiter within max_frame_bytes: discarded up to the next 0x00


@dataclass(frozen=True)
class Frame:
    """A frame that decoded cleanly; ``raw`` is its wire bytes including the delimiter."""

    seq: int
    msg_type: MsgType
    msg: Message
    raw: bytes


@dataclass(frozen=True)
class DecodeError:
    """A discarded frame: the kind, a human-readable detail and the bytes dropped."""

    kind: DecodeErrorKind
    detail: str
    raw: bytes


def encode_raw_frame(msg_type: int, seq: int, payload: bytes, version: int = PROTOCOL_VERSION) -> bytes:
    """Wire bytes for an arbitrary header and payload (no payload checks; for tests and tools)."""
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"payload of {len(payload)} bytes exceeds {MAX_PAYLOAD}")
    body = _HEADER.pack(version & 0xFF, msg_type & 0xFF, seq & 0xFFFF, len(payload)) + payload
    return cobs.encode(body + _CRC.pack(crc16(body))) + b"\x00"


def encode_frame(msg: Message, seq: int, schema: WireSchema | None = None) -> bytes:
    """Complete wire bytes of ``msg`` with sequence ``seq`` (taken modulo 2**16), delimiter included,
    payload in ``schema`` (default: the u16 schema).

    Raises :class:`protocol.codec.PayloadError` for a structurally invalid message.
    """
    schema = schema or WIRE_SCHEMA_16
    payload: bytes | None = None
    fc = fast_for(schema)
    if fc is not None:
        enc = fc.encoders.get(msg.__class__)
        if enc is not None:
            try:
                payload = enc(msg)
            except FAST_ERRORS:
                payload = None
            if payload is not None:
                body = _HEADER.pack(PROTOCOL_VERSION, _FAST_TYPES[msg.__class__], seq & 0xFFFF, len(payload)) + payload
                return cobs.encode(body + _CRC.pack(crc16(body))) + b"\x00"
    return encode_raw_frame(msg_type_of(msg), seq, schema.encode_payload(msg))


def frame_size(msg: Message, schema: WireSchema | None = None) -> int:
    """Bytes ``msg`` occupies on the wire (exact below 248 payload bytes; +-1 above, COBS is data-dependent)."""
    return len(encode_frame(msg, 0, schema))


def _decode_block(block: bytes, raw: bytes, schema: WireSchema = WIRE_SCHEMA_16) -> Frame | DecodeError:
    """Decode one delimiter-free block; ``raw`` is what to report (block + delimiter)."""
    try:
        body = cobs.decode(block)
    except cobs.DecodeError as e:
        return DecodeError(DecodeErrorKind.COBS, f"invalid COBS: {e}", raw)
    if len(body) < HEADER_SIZE + CRC_SIZE:
        return DecodeError(
            DecodeErrorKind.LENGTH, f"{len(body)} byte(s) decoded, a frame has at least {HEADER_SIZE + CRC_SIZE}", raw
        )
    (crc_rx,) = _CRC.unpack_from(body, len(body) - CRC_SIZE)
    crc_calc = crc16(body[:-CRC_SIZE])
    if crc_rx != crc_calc:
        return DecodeError(
            DecodeErrorKind.CRC, f"CRC mismatch: frame says {crc_rx:#06x}, bytes give {crc_calc:#06x}", raw
        )
    version, type_byte, seq, length = _HEADER.unpack_from(body)
    if version != PROTOCOL_VERSION:
        return DecodeError(
            DecodeErrorKind.VERSION, f"protocol version {version}, this end speaks {PROTOCOL_VERSION}", raw
        )
    n_payload = len(body) - HEADER_SIZE - CRC_SIZE
    if length != n_payload:
        return DecodeError(
            DecodeErrorKind.LENGTH, f"length field says {length} payload byte(s), frame has {n_payload}", raw
        )
    msg_type = _MSG_TYPES.get(type_byte)
    if msg_type is None:
        return DecodeError(DecodeErrorKind.UNKNOWN_TYPE, f"unknown message type {type_byte:#04x} (seq {seq})", raw)
    payload = body[HEADER_SIZE:-CRC_SIZE]
    fc = fast_for(schema)
    dec = fc.decoders.get(msg_type) if fc is not None else None
    fast = dec(payload) if dec is not None else None
    if fast is not None:
        return Frame(seq=seq, msg_type=msg_type, msg=fast, raw=raw)
    try:
        msg = schema.decode_payload(msg_type, payload)
    except PayloadError as e:
        return DecodeError(DecodeErrorKind.PAYLOAD, f"seq {seq}: {e}", raw)
    return Frame(seq=seq, msg_type=msg_type, msg=msg, raw=raw)


#: the message types :mod:`protocol.fastcodec` packs, by class
_FAST_TYPES: dict[type, int] = {Telemetry: int(MsgType.TELEMETRY), SimState: int(MsgType.SIM_STATE),
                                ServoFrame: int(MsgType.SERVO_FRAME)}

#: type byte -> MsgType: a dict lookup (calling an Enum class runs its metaclass's Python ``__call__``: 0.47 us, the lookup 0.03)
_MSG_TYPES: dict[int, MsgType] = {t.value: t for t in MsgType}

_ERROR_KINDS = tuple(DecodeErrorKind)  # iterating an Enum runs Python code; a decoder per input (fuzzing) pays it


class FrameDecoder:
    """Incremental decoder: feed any byte chunks, get frames and error events in order.

    Never raises on input. Holds at most ``max_frame_bytes`` undelimited bytes:
    a longer run is dropped and reported once as ``OVERSIZE``, and everything up
    to the next 0x00 is discarded (counted in ``bytes_discarded``). Counters:
    ``frames_ok``, ``errors`` (per :class:`DecodeErrorKind`), ``bytes_discarded``
    (bytes of every discarded frame or run) and ``bytes_received``. Payloads decode with ``schema``
    (default: the u16 schema); the attribute may be changed between feeds.
    """

    def __init__(self, max_frame_bytes: int = DEFAULT_MAX_FRAME_BYTES, schema: WireSchema | None = None) -> None:
        if max_frame_bytes < MAX_WIRE_FRAME:
            raise ValueError(f"max_frame_bytes must be at least {MAX_WIRE_FRAME} (longest valid frame)")
        self.max_frame_bytes = max_frame_bytes
        self.schema: WireSchema = schema or WIRE_SCHEMA_16
        self._buf = bytearray()
        self._skipping = False  # discarding an oversize run until the next delimiter
        self.frames_ok = 0
        self.errors: dict[DecodeErrorKind, int] = dict.fromkeys(_ERROR_KINDS, 0)
        self.bytes_discarded = 0
        self.bytes_received = 0

    @property
    def error_count(self) -> int:
        """Total errors of every kind."""
        return sum(self.errors.values())

    @property
    def pending(self) -> int:
        """Bytes buffered while waiting for a delimiter (never above ``max_frame_bytes``)."""
        return len(self._buf)

    def reset(self) -> None:
        """Drop buffered bytes (e.g. after the port was reopened); counters are kept."""
        self.bytes_discarded += len(self._buf)
        self._buf.clear()
        self._skipping = False

    def _error(self, err: DecodeError, out: list[Frame | DecodeError]) -> None:
        self.errors[err.kind] += 1
        self.bytes_discarded += len(err.raw)
        out.append(err)

    def feed(self, data: bytes) -> list[Frame | DecodeError]:
        """Consume ``data``; return the frames and errors completed by it, in wire order."""
        out: list[Frame | DecodeError] = []
        data = bytes(data)
        n = len(data)
        self.bytes_received += n
        # one C-level split per call rather than a Python step per delimiter: the fuzz targets (and a
        # noisy line) feed many short or empty blocks; empty ones (idle delimiters) are skipped in C
        blocks = data.split(b"\x00")
        tail = blocks.pop()  # the bytes after the last delimiter (all of ``data`` when it has none)
        if blocks:
            first = blocks[0]
            if self._skipping:  # the end of an oversize run: discarded with its delimiter
                self.bytes_discarded += len(first) + 1
                self._skipping = False
                blocks[0] = b""
            elif self._buf:
                self._buf += first
                blocks[0] = bytes(self._buf)
                self._buf.clear()
            limit = self.max_frame_bytes
            schema = self.schema
            for block in filter(None, blocks):
                if len(block) > limit:
                    self._error(
                        DecodeError(
                            DecodeErrorKind.OVERSIZE, f"{len(block)} bytes without a delimiter (limit {limit})",
                            block[:limit],
                        ),
                        out,
                    )
                    self.bytes_discarded += len(block) + 1 - limit
                    continue
                item = _decode_block(block, block + b"\x00", schema)
                if isinstance(item, Frame):
                    self.frames_ok += 1
                    out.append(item)
                else:
                    self._error(item, out)
        if tail:
            if self._skipping:
                self.bytes_discarded += len(tail)
                return out
            room = self.max_frame_bytes + 1 - len(self._buf)
            self._buf += tail[:room]
            if len(self._buf) > self.max_frame_bytes:
                self._oversize(out)
                self.bytes_discarded += max(0, len(tail) - room)
        return out

    def _oversize(self, out: list[Frame | DecodeError]) -> None:
        dropped = bytes(self._buf[: self.max_frame_bytes])
        extra = len(self._buf) - len(dropped)
        self._buf.clear()
        self._skipping = True
        self._error(
            DecodeError(
                DecodeErrorKind.OVERSIZE,
                f"more than {self.max_frame_bytes} bytes without a delimiter; skipping to the next 0x00",
                dropped,
            ),
            out,
        )
        self.bytes_discarded += extra
