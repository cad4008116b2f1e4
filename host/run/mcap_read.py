"""Reading a run's ``run.mcap`` back (the ``mcap`` package; protobuf channels via ``mcap-protobuf-support``).

:class:`McapRun` opens a file written by :mod:`host.run.mcap_log`:

* :meth:`McapRun.counts` -> ``{topic: messages}`` from the summary's statistics (a complete file), or
  counted by reading every record (a file whose writer was killed: no summary);
* :meth:`McapRun.messages` -> :class:`McapMessage` (topic, schema name, log time ns, decoded value:
  a dict for JSON channels, the protobuf message as a dict for the SDK's typed channels), in log-time
  order for a complete file and in file order for a cut one;
* :attr:`McapRun.truncated` -> None, or one line saying where a cut file ends (its writer was killed:
  everything up to the last complete chunk is read, as the format allows).

Big messages: with ``summarise_over=N`` a message whose encoded payload is over N bytes is not turned into
a dict (a robot's ``/scene`` is megabytes: as a dict and then JSON, one took seconds and printed a line
of tens of MB); its value is a :class:`MessageSummary` instead: schema, payload bytes, and how many
elements each repeated message field holds (``entities``, ``models``, ``points``...), counted on the
decoded protobuf without converting it (a JSON channel: its top-level lists' lengths).

For replay: :func:`read_mcap_host_to_board` yields the ``/link/tx`` messages (re-decoded from their
serial wire bytes) in send order, :func:`mcap_last_sim_state` the last ``/sim_state``.

Errors: :class:`McapReadError` (a ``ValueError``; one line) for a file that is not an MCAP at all.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mcap.decoder import DecoderFactory as McapDecoderFactory
from mcap.exceptions import McapError
from mcap.reader import SeekingReader
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader

from protocol import framelog
from protocol.framing import Frame
from protocol.messages import Message as WireMessage
from protocol.messages import SimState

__all__ = ["McapMessage", "McapReadError", "McapRun", "MessageSummary", "mcap_last_sim_state", "read_mcap_host_to_board",
           "summarise"]

#: what the mcap package raises where a cut file ends: a record cut inside one of its fixed-size fields
#: surfaces as ``struct.error`` from its stream reader ("unpack requires a buffer of 2 bytes"), which
#: ended ``ghostshell log decode`` with a traceback instead of the one line
_CUT_ERRORS = (McapError, ValueError, EOFError, struct.error)


class McapReadError(ValueError):
    """The file is not a readable MCAP (the message says why)."""


@dataclass(frozen=True)
class McapMessage:
    topic: str
    schema: str
    log_time_ns: int
    value: Any
    size: int = 0  # the encoded payload's bytes


@dataclass(frozen=True)
class MessageSummary:
    """A message too big to show: its schema, its encoded payload's size (bytes) and element counts per
    repeated field name (summed over the whole message, e.g. ``{"entities": 7, "models": 13}``)."""

    schema: str
    size: int
    counts: dict[str, int]

    def __str__(self) -> str:
        counts = ", ".join(f"{k} {v}" for k, v in self.counts.items())
        return f"<{self.schema or 'message'}: {self.size} B{'; ' + counts if counts else ''}>"


def _has_repeated_messages(descriptor: Any, seen: dict[Any, bool]) -> bool:
    """Whether messages of ``descriptor`` hold a repeated message field anywhere below (cached)."""
    if descriptor in seen:
        return seen[descriptor]
    seen[descriptor] = False  # (a recursive schema: no deeper than this)
    out = False
    for fd in descriptor.fields:
        if fd.message_type is not None and (fd.is_repeated
                                             or _has_repeated_messages(fd.message_type, seen)):
            out = True
            break
    seen[descriptor] = out
    return out


def _count_protobuf(msg: Any, counts: dict[str, int], seen: dict[Any, bool]) -> None:
    for fd, v in msg.ListFields():
        if fd.message_type is None:
            continue
        if fd.is_repeated:
            counts[fd.name] = counts.get(fd.name, 0) + len(v)
            if _has_repeated_messages(fd.message_type, seen):  # (a list of points: its length is enough)
                for item in v:
                    _count_protobuf(item, counts, seen)
        elif _has_repeated_messages(fd.message_type, seen):
            _count_protobuf(v, counts, seen)


def summarise(value: Any, schema: str, size: int) -> MessageSummary:
    """``value`` (a decoded protobuf message, a JSON channel's dict, or bytes) as a :class:`MessageSummary`."""
    counts: dict[str, int] = {}
    if hasattr(value, "DESCRIPTOR"):
        _count_protobuf(value, counts, {})
    elif isinstance(value, dict):
        counts = {k: len(v) for k, v in value.items() if isinstance(v, (list, dict, str))}
    return MessageSummary(schema, size, counts)


class _JsonDecoderFactory(McapDecoderFactory):
    """JSON channels (``message_encoding`` json) decoded with :func:`json.loads`."""

    def decoder_for(self, message_encoding: str, schema: Schema | None) -> Any:
        return json.loads if message_encoding == "json" else None


class _RawDecoderFactory(McapDecoderFactory):
    """Anything else: the bytes as they are."""

    def decoder_for(self, message_encoding: str, schema: Schema | None) -> Any:
        return bytes


def _factories() -> list[McapDecoderFactory]:
    out: list[McapDecoderFactory] = [_JsonDecoderFactory()]
    try:
        from mcap_protobuf.decoder import DecoderFactory
    except ImportError:  # decoding protobuf needs protobuf; JSON channels still read
        pass
    else:
        out.append(DecoderFactory())
    return [*out, _RawDecoderFactory()]


def _to_plain(value: Any) -> Any:
    if hasattr(value, "DESCRIPTOR"):
        from google.protobuf.json_format import MessageToDict

        return MessageToDict(value, preserving_proto_field_name=True, always_print_fields_with_no_presence=True)
    return value


class McapRun:
    """A run's MCAP (see the module docstring)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.truncated: str | None = None
        try:
            with open(self.path, "rb") as f:
                head = f.read(8)
        except OSError as e:
            raise McapReadError(f"cannot read {self.path}: {e.strerror or e}") from None
        if head != b"\x89MCAP0\r\n":
            raise McapReadError(f"{self.path} is not an MCAP file (no MCAP magic)")
        self._summary: Any = None
        try:
            with open(self.path, "rb") as f:
                self._summary = SeekingReader(f).get_summary()
        except (*_CUT_ERRORS, OSError):
            self._summary = None

    @property
    def complete(self) -> bool:
        """True when the file has its summary (its writer closed it)."""
        return self._summary is not None and self._summary.statistics is not None

    def metadata(self) -> dict[str, dict[str, str]]:
        """The metadata records by name (e.g. ``run``: robot, scene, link, clock)."""
        out: dict[str, dict[str, str]] = {}
        for rec in self._records(want=("Metadata",)):
            out[rec.name] = dict(rec.metadata)
        return out

    def counts(self) -> dict[str, int]:
        """Messages per topic."""
        if self.complete:
            s = self._summary
            return {s.channels[cid].topic: n for cid, n in sorted(s.statistics.channel_message_counts.items())}
        out: dict[str, int] = {}
        for m in self.messages(decode=False):
            out[m.topic] = out.get(m.topic, 0) + 1
        return out

    def messages(self, topics: Iterable[str] | None = None, *, decode: bool = True,
                 log_time_order: bool = True, summarise_over: int | None = None) -> Iterator[McapMessage]:
        """The messages on ``topics`` (all when None); see the module docstring for the order, and for
        ``summarise_over`` (bytes; None: every message in full)."""
        wanted = set(topics) if topics is not None else None
        factories = _factories() if decode else []
        if self.complete:
            decoders: dict[int, Any] = {}
            with open(self.path, "rb") as f:
                reader = SeekingReader(f)
                for schema, channel, message in reader.iter_messages(topics=list(wanted) if wanted else None,
                                                                     log_time_order=log_time_order):
                    value = _decode(decoders, factories, channel, schema, message.data) if decode else None
                    yield self._message(schema, channel, message, value, decode, summarise_over)
            return
        yield from self._stream(wanted, factories, decode, summarise_over)

    def _message(self, schema: Schema | None, channel: Channel, message: Message, value: Any,
                 decode: bool, summarise_over: int | None = None) -> McapMessage:
        name = schema.name if schema else ""
        size = len(message.data)
        if not decode:
            value = message.data
        elif summarise_over is not None and size > summarise_over:
            value = summarise(value, name, size)
        else:
            value = _to_plain(value)
        return McapMessage(channel.topic, name, message.log_time, value, size)

    def _stream(self, wanted: set[str] | None, factories: list[Any], decode: bool,
                summarise_over: int | None = None) -> Iterator[McapMessage]:
        """Every message of a cut file in file order, up to where it ends."""
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        decoders: dict[int, Any] = {}
        n = 0
        with open(self.path, "rb") as f:
            records = StreamReader(f, skip_magic=False, emit_chunks=False).records
            try:
                for rec in records:
                    if isinstance(rec, Schema):
                        schemas[rec.id] = rec
                    elif isinstance(rec, Channel):
                        channels[rec.id] = rec
                    elif isinstance(rec, Message):
                        ch = channels.get(rec.channel_id)
                        if ch is None or (wanted is not None and ch.topic not in wanted):
                            continue
                        n += 1
                        schema = schemas.get(ch.schema_id)
                        value = _decode(decoders, factories, ch, schema, rec.data) if decode else None
                        yield self._message(schema, ch, rec, value, decode, summarise_over)
            except _CUT_ERRORS:
                self.truncated = (f"{self.path} was cut mid-record (its writer did not finish it): read {n} "
                                  f"message(s), up to its last complete chunk")
                return
        if not self.complete:
            self.truncated = f"{self.path} has no summary (its writer did not finish it); read {n} message(s)"

    def _records(self, want: tuple[str, ...]) -> Iterator[Any]:
        with open(self.path, "rb") as f:
            if self.complete:
                reader = SeekingReader(f)
                if "Metadata" in want:
                    yield from reader.iter_metadata()
                return
            try:
                for rec in StreamReader(f, skip_magic=False, emit_chunks=False).records:
                    if type(rec).__name__ in want:
                        yield rec
            except _CUT_ERRORS:
                return


def _decode(decoders: dict[int, Any], factories: list[Any], channel: Channel, schema: Schema | None,
            data: bytes) -> Any:
    """``data`` decoded by the first factory that knows the channel's encoding (cached per channel)."""
    dec = decoders.get(channel.id)
    if dec is None:
        for fac in factories:
            dec = fac.decoder_for(channel.message_encoding, schema)
            if dec is not None:
                decoders[channel.id] = dec
                break
    return dec(data) if dec is not None else data


def read_mcap_host_to_board(path: Path) -> Iterator[tuple[float, int, WireMessage]]:
    """``(t board s, seq, message)`` the host sent, in send order, from the ``/link/tx`` channel."""
    try:
        run = McapRun(path)
    except McapReadError as e:
        raise ValueError(str(e)) from None
    for m in run.messages(["/link/tx"], log_time_order=False):
        raw = m.value.get("raw") if isinstance(m.value, dict) else None
        if not raw:
            continue
        item = framelog.decode_raw(raw)
        if isinstance(item, Frame):
            yield m.log_time_ns * 1e-9, item.seq, item.msg


def mcap_last_sim_state(path: Path) -> SimState | None:
    """The last ``/sim_state`` (the ground truth the recording host saw last), or None."""
    last: SimState | None = None
    try:
        run = McapRun(path)
    except McapReadError:
        return None
    for m in run.messages(["/sim_state"], log_time_order=False):
        v = m.value
        if not isinstance(v, dict):
            continue
        s = SimState(int(v["board_time_us"]), tuple(v["base_pos"]), tuple(v["base_quat"]),  # type: ignore[arg-type]
                     int(v.get("objects", 0)), int(v.get("toppled", 0)))
        if last is None or s.board_time_us >= last.board_time_us:
            last = s
    return last
