"""Reading a run's ``run.mcap`` back (the ``mcap`` package; protobuf channels via ``mcap-protobuf-support``).

:class:`McapRun` opens a file written by :mod:`host.run.mcap_log`:

* :meth:`McapRun.counts` -> ``{topic: messages}`` from the summary's statistics (a complete file), or
  counted by reading every record (a file whose writer was killed: no summary);
* :meth:`McapRun.messages` -> :class:`McapMessage` (topic, schema name, log time ns, decoded value:
  a dict for JSON channels, the protobuf message as a dict for the SDK's typed channels), in log-time
  order for a complete file and in file order for a cut one;
* :attr:`McapRun.truncated` -> None, or one line saying where a cut file ends (its writer was killed:
  everything up to the last complete chunk is read, as the format allows).

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

__all__ = ["McapMessage", "McapReadError", "McapRun", "mcap_last_sim_state", "read_mcap_host_to_board"]

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
                 log_time_order: bool = True) -> Iterator[McapMessage]:
        """The messages on ``topics`` (all when None); see the module docstring for the order."""
        wanted = set(topics) if topics is not None else None
        factories = _factories() if decode else []
        if self.complete:
            with open(self.path, "rb") as f:
                reader = SeekingReader(f, decoder_factories=factories)
                it = reader.iter_decoded_messages(topics=list(wanted) if wanted else None,
                                                  log_time_order=log_time_order) if decode else \
                    ((s, c, m, None) for s, c, m in reader.iter_messages(topics=list(wanted) if wanted else None,
                                                                         log_time_order=log_time_order))
                for schema, channel, message, value in it:
                    yield self._message(schema, channel, message, value, decode)
            return
        yield from self._stream(wanted, factories, decode)

    def _message(self, schema: Schema | None, channel: Channel, message: Message, value: Any,
                 decode: bool) -> McapMessage:
        return McapMessage(channel.topic, schema.name if schema else "", message.log_time,
                           _to_plain(value) if decode else message.data)

    def _stream(self, wanted: set[str] | None, factories: list[Any], decode: bool) -> Iterator[McapMessage]:
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
                        value: Any = None
                        if decode:
                            dec = decoders.get(ch.id)
                            if dec is None:
                                for fac in factories:
                                    dec = fac.decoder_for(ch.message_encoding, schema)
                                    if dec is not None:
                                        decoders[ch.id] = dec
                                        break
                            value = dec(rec.data) if dec is not None else rec.data
                        yield self._message(schema, ch, rec, value, decode)
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
