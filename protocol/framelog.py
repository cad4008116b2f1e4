"""Frame-log records shared by both ends of the serial link (pure functions, no I/O).

Serial frames have no standard capture format or tool (pcap has no link type for a
custom UART protocol), so the log is JSON Lines: one object per frame, written by
whoever owns the file. CAN frames will use python-can's writers (``can.Logger``,
e.g. ASC/BLF) instead. A record is::

    {"dir": "tx"|"rx", "t": seconds, "raw": "<wire bytes as hex, delimiter included>",
     "seq": 42, "type": "SERVO_FRAME", "fields": {...}}          # decoded frame
    {"dir": ..., "t": ..., "raw": ..., "error": "CRC", "detail": "..."}   # discarded bytes

``fields`` holds the decoded message: enums by name, flags as ``"A|B"``, tuples as
lists, bytes as hex, NaN as ``null``. The raw bytes alone are enough to re-decode
a record (:func:`decode_raw`), so a log stays useful if the field rendering changes.

Which robot a log is for: the payloads of SERVO_FRAME, FLUSH and TELEMETRY depend on the robot's
wire schema (:class:`protocol.codec.WireSchema`: u16 servo mask up to 16 servos, u32 above). A log
says which itself: every session starts with HELLO (host -> board) and CAPS (board -> host), whose
layouts are the same for every robot and which carry the schema hash. :class:`LogDecoder`
re-decodes a log's raw bytes with the schema its latest HELLO/CAPS named; before the first one (a
realtime board's reports before a host connected) it takes the first schema that decodes the frame,
the u16 one first. That is unambiguous: a SERVO_FRAME or FLUSH of one schema never decodes under the
other (the length check fails), and a TELEMETRY decodes the same under both. Logs of robots with up
to 16 servos (every log written before robots became data) decode exactly as before.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
from collections.abc import Iterable, Iterator
from enum import Enum, IntFlag
from typing import Any

from protocol.codec import WIRE_SCHEMAS, WireSchema, schema_by_hash
from protocol.framing import DecodeError, DecodeErrorKind, Frame, FrameDecoder
from protocol.messages import Caps, Hello

__all__ = [
    "FrameLogError",
    "LogDecoder",
    "decode_raw",
    "format_fields",
    "format_record",
    "from_line",
    "iter_records",
    "message_fields",
    "record",
    "to_line",
]

DIRECTIONS = ("tx", "rx")


class FrameLogError(ValueError):
    """A log line or raw hex string that cannot be read."""


def _jsonable(value: Any) -> Any:
    t = type(value)
    if t is float:  # the common cases first, by exact type (a frame's targets, a report's positions)
        return value if math.isfinite(value) else None
    if t is int or t is str or value is None:
        return value
    if t is tuple or t is list:
        return [_jsonable(v) for v in value]
    if isinstance(value, IntFlag):
        return _flag_names(value)
    if isinstance(value, Enum):
        return value.name
    if isinstance(value, bool) or isinstance(value, (int, str)):
        return value
    if isinstance(value, float):
        return None if not math.isfinite(value) else value
    if isinstance(value, (bytes, bytearray, memoryview)):
        return bytes(value).hex()
    if isinstance(value, (tuple, list)):
        return [_jsonable(v) for v in value]
    return str(value)


@functools.lru_cache(maxsize=4096, typed=True)  # typed: equal values of two flag classes differ
def _flag_names(value: IntFlag) -> str:
    """``"A|B"``: the named members set in ``value`` (``"NONE"`` for none); cached, a log repeats few."""
    return "|".join(e.name for e in type(value) if e.name is not None and e.value and (value & e) == e) or "NONE"


_FIELD_NAMES: dict[type, tuple[str, ...]] = {}  # one entry per message class


def message_fields(msg: Any) -> dict[str, Any]:
    """A message dataclass as a JSON-ready dict (enums by name, bytes as hex, NaN as None)."""
    cls = type(msg)
    names = _FIELD_NAMES.get(cls)
    if names is None:
        names = _FIELD_NAMES[cls] = tuple(f.name for f in dataclasses.fields(msg))
    return {name: _jsonable(getattr(msg, name)) for name in names}


def decode_raw(raw: str | bytes, schema: WireSchema | None = None) -> Frame | DecodeError:
    """Decode one frame from its wire bytes (hex string or bytes; the delimiter may be missing) with
    ``schema`` (default: the u16 schema; :class:`LogDecoder` follows a log's own).

    Raises :class:`FrameLogError` only when ``raw`` is not valid hex.
    """
    if isinstance(raw, str):
        try:
            data = bytes.fromhex(raw)
        except ValueError as e:
            raise FrameLogError(f"raw is not a hex string: {e}") from None
    else:
        data = bytes(raw)
    if not data.endswith(b"\x00"):
        data += b"\x00"
    items = FrameDecoder(max_frame_bytes=max(512, len(data)), schema=schema).feed(data)
    if len(items) == 1:
        return items[0]
    if not items:
        return DecodeError(DecodeErrorKind.LENGTH, "no frame in the raw bytes (empty)", data)
    kinds = ", ".join(type(i).__name__ if isinstance(i, Frame) else i.kind.value for i in items)
    return DecodeError(DecodeErrorKind.COBS, f"raw bytes hold {len(items)} frames/errors ({kinds}), expected one", data)


class LogDecoder:
    """Re-decodes the raw bytes of one log's records in file order with the log's own wire schema
    (see the module docstring); ``schema`` pins one instead. ``.schema`` is the one in effect (None
    until a HELLO/CAPS named one)."""

    def __init__(self, schema: WireSchema | None = None) -> None:
        self.pinned = schema is not None
        self.schema: WireSchema | None = schema

    def decode(self, raw: str | bytes) -> Frame | DecodeError:
        """The frame (or the error) in one record's raw bytes; :class:`FrameLogError` for bad hex."""
        if self.schema is not None:
            item = decode_raw(raw, self.schema)
        else:
            item = decode_raw(raw, WIRE_SCHEMAS[0])
            if isinstance(item, DecodeError) and item.kind is DecodeErrorKind.PAYLOAD:
                for other in WIRE_SCHEMAS[1:]:
                    again = decode_raw(raw, other)
                    if isinstance(again, Frame):
                        item = again
                        break
        if not self.pinned and isinstance(item, Frame) and isinstance(item.msg, (Hello, Caps)):
            named = schema_by_hash(item.msg.schema_hash)
            if named is not None:
                self.schema = named
        return item


def record(direction: str, t: float, raw: bytes, item: Frame | DecodeError | None = None,
           schema: WireSchema | None = None) -> dict[str, Any]:
    """Build one log record; when ``item`` is None the raw bytes are decoded here (with ``schema``)."""
    if direction not in DIRECTIONS:
        raise ValueError(f"direction must be 'tx' or 'rx', got {direction!r}")
    if item is None:
        item = decode_raw(bytes(raw), schema)
    rec: dict[str, Any] = {"dir": direction, "t": float(t), "raw": bytes(raw).hex()}
    if isinstance(item, Frame):
        rec["seq"] = item.seq
        rec["type"] = item.msg_type.name
        rec["fields"] = message_fields(item.msg)
    else:
        rec["error"] = item.kind.value
        rec["detail"] = item.detail
    return rec


def to_line(rec: dict[str, Any]) -> str:
    """One compact JSON line (no trailing newline)."""
    return json.dumps(rec, separators=(",", ":"), allow_nan=False)


def from_line(line: str) -> dict[str, Any]:
    """Parse and check one log line; :class:`FrameLogError` with the reason if it is not a record."""
    text = line.strip()
    if not text:
        raise FrameLogError("empty line")
    try:
        rec = json.loads(text)
    except json.JSONDecodeError as e:
        raise FrameLogError(f"not JSON: {e.msg} at column {e.colno}") from None
    if not isinstance(rec, dict):
        raise FrameLogError(f"expected a JSON object, got {type(rec).__name__}")
    if rec.get("dir") not in DIRECTIONS:
        raise FrameLogError(f"'dir' must be 'tx' or 'rx', got {rec.get('dir')!r}")
    t = rec.get("t")
    if isinstance(t, bool) or not isinstance(t, (int, float)):
        raise FrameLogError(f"'t' must be a number, got {t!r}")
    raw = rec.get("raw")
    if not isinstance(raw, str):
        raise FrameLogError(f"'raw' must be a hex string, got {raw!r}")
    try:
        bytes.fromhex(raw)
    except ValueError:
        raise FrameLogError(f"'raw' is not valid hex: {raw[:40]!r}") from None
    if "error" in rec:
        if not isinstance(rec["error"], str):
            raise FrameLogError("'error' must be a string")
    elif not (isinstance(rec.get("type"), str) and isinstance(rec.get("fields"), dict)):
        raise FrameLogError("a record needs either 'type' and 'fields' or 'error'")
    return rec


def iter_records(lines: Iterable[str]) -> Iterator[dict[str, Any]]:
    """Parse lines of a log (blank lines skipped); errors name the 1-based line number."""
    for lineno, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            yield from_line(line)
        except FrameLogError as e:
            raise FrameLogError(f"line {lineno}: {e}") from None


def _fmt_value(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, list):
        return "[" + " ".join(_fmt_value(x) for x in v) + "]"
    if v is None:
        return "nan"
    return str(v)


def format_record(rec: dict[str, Any]) -> str:
    """One readable line, e.g. ``  12.345678 tx #   42 SERVO_FRAME      39 B  apply_at_us=... mask=0x0fff ...``."""
    n = len(rec.get("raw", "")) // 2
    head = f"{float(rec['t']):12.6f} {rec['dir']}"
    if "error" in rec:
        return f"{head} ERROR {rec['error']:<12} {n:4d} B  {rec.get('detail', '')}  raw={rec.get('raw', '')[:64]}"
    return f"{head} #{rec.get('seq', 0):5d} {rec['type']:<17} {n:4d} B  " + format_fields(rec.get("fields", {}))


def format_fields(fields: dict[str, Any]) -> str:
    """A message's fields (:func:`message_fields`) as ``key=value`` words, the one layout of every
    ``ghostshell log decode`` (serial and CAN): a servo mask in hex (``mask=0x0fff``), binary data
    by its length, numbers with up to six significant digits."""
    parts = []
    for key, value in fields.items():
        if key == "mask" and isinstance(value, int):
            parts.append(f"mask={value:#06x}")
        elif key == "data" and isinstance(value, str):
            parts.append(f"data=<{len(value) // 2} B>")
        else:
            parts.append(f"{key}={_fmt_value(value)}")
    return " ".join(parts)
