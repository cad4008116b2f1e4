"""Frame-log files, shared by both ends: one writer per format, chosen by the file's suffix.

The one module of ``protocol/`` that touches files (a thin layer: open, append one record, close);
the encoding is elsewhere and pure. Like python-can's ``can.Logger`` (which picks its writer by
suffix), :func:`open_frame_log` picks a writer by the path's suffix among the formats that can hold
the link's wire units:

==========================  =====================================================  ==================
wire unit                   suffix -> format                                       encoding
==========================  =====================================================  ==================
serial frame (COBS bytes)   any -> JSON Lines (serial frames have no standard      :mod:`protocol.framelog`
                            capture format; the name is kept as given)
CAN frame                   ``.log`` candump ``-L``, ``.asc``, ``.blf``, ``.csv``, python-can's writers
                            ``.trc`` ... (python-can's own table); ``.jsonl`` (the  (``can.Logger``)
                            serial name) becomes the same name with ``.log``
==========================  =====================================================  ==================

A record is written when its unit went to (``"tx"``) or came from (``"rx"``) the wire, with the
direction the caller knows, never a driver's guess: python-can marks every frame SocketCAN loops
back on a ``vcan`` interface as sent, the board's telemetry included. A sent serial frame is logged
as its wire bytes decode (quantised values, exactly what the receiver's log shows for the same
``raw``), not as the message object before encoding. JSON Lines times are the caller's clock
(board seconds on the board, ``time.monotonic`` on the host); CAN records carry wall-clock time
(``time.time``, or the driver's receive timestamp) so two ends' captures merge. python-can is
imported only for CAN logs (it is the CAN transports' library: :mod:`protocol.can.pycan`).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from pathlib import Path
from typing import IO, Any

from protocol import framelog
from protocol.can.frame import CanFrame
from protocol.codec import WireSchema
from protocol.framing import DecodeError, Frame

__all__ = ["CanFrameLog", "FrameLogWriter", "JsonlFrameLog", "WIRES", "can_log_path", "open_frame_log"]

#: the wire units a frame log can hold
WIRES = ("serial", "can")


class FrameLogWriter(ABC):
    """One frame log file; ``records`` counts what was written. Writing after :meth:`close` does nothing."""

    wire: str = ""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.records = 0

    def write_serial(self, direction: str, t: float, raw: bytes, item: Frame | DecodeError | None = None) -> None:
        """One serial frame (``raw`` = its wire bytes); ``item`` None: decoded from ``raw`` here."""
        raise TypeError(f"a {type(self).__name__} holds {self.wire} units, not serial frames")

    def write_can(self, direction: str, frame: CanFrame, t: float | None = None) -> None:
        """One CAN frame; ``t`` wall-clock seconds (None: now)."""
        raise TypeError(f"a {type(self).__name__} holds {self.wire} units, not CAN frames")

    @abstractmethod
    def close(self) -> None:
        """Flush and close the file (idempotent)."""


class JsonlFrameLog(FrameLogWriter):
    """JSON Lines (:mod:`protocol.framelog`), line-buffered: a crash loses at most the line being written
    (and, on the host's serial link, the records noted but not yet handed to it: ``host.link.deferred``).

    ``schema`` is the wire schema sent frames are decoded with (settable: a session switches it
    after CAPS). ``lazy``: the file is created with the first record, so a link that never opened
    leaves no empty log behind; else at once (``OSError`` now, not later).
    """

    wire = "serial"

    def __init__(self, path: Path, *, schema: WireSchema | None = None, lazy: bool = False) -> None:
        super().__init__(path)
        self.schema = schema
        self._f: IO[str] | None = None
        self._closed = False
        if not lazy:
            self._open()

    def _open(self) -> IO[str]:
        self._f = open(self.path, "w", buffering=1, encoding="utf-8")
        return self._f

    def write_serial(self, direction: str, t: float, raw: bytes, item: Frame | DecodeError | None = None) -> None:
        f = self._f
        if f is None:
            if self._closed:
                return
            f = self._open()
        f.write(framelog.to_line(framelog.record(direction, t, raw, item, self.schema)) + "\n")
        self.records += 1

    def close(self) -> None:
        self._closed = True
        if self._f is not None:
            self._f.close()
            self._f = None


def can_log_path(path: str | Path) -> Path:
    """Where a CAN log asked for as ``path`` goes: a serial-style ``.jsonl`` name becomes ``.log`` (candump)."""
    p = Path(path)
    return p.with_suffix(".log") if p.suffix.lower() == ".jsonl" else p


class CanFrameLog(FrameLogWriter):
    """python-can's writer for the path's suffix (``can.Logger``); ``channel`` names the bus in every record.

    Raises ``ValueError`` (one line naming the suffixes to use) for a suffix python-can has no writer for.
    """

    wire = "can"

    def __init__(self, path: Path, *, channel: str = "can0") -> None:
        super().__init__(can_log_path(path))
        import can

        from protocol.can.pycan import to_can_message

        self._to_message = to_can_message
        self.channel = channel
        try:
            self._writer: Any = can.Logger(str(self.path))  # type: ignore[no-untyped-call]
        except ValueError as e:
            raise ValueError(f"cannot log CAN frames to {self.path}: {e} (use .log, .asc or .blf)") from None

    def write_can(self, direction: str, frame: CanFrame, t: float | None = None) -> None:
        if self._writer is None:
            return
        self._writer.on_message_received(self._to_message(frame, self.channel, direction == "rx", t))
        self.records += 1

    def close(self) -> None:
        writer, self._writer = self._writer, None
        if writer is not None:
            try:
                writer.stop()
            except Exception:  # a log that cannot be finished must not take the link down with it
                pass


def open_frame_log(path: str | Path, wire: str, *, schema: WireSchema | None = None, lazy: bool = False,
                   channel: str = "can0") -> FrameLogWriter:
    """The writer for ``path`` holding ``wire`` units (``"serial"`` or ``"can"``; see the module docstring).

    ``schema``/``lazy`` apply to JSON Lines, ``channel`` to CAN logs. Raises ``ValueError`` for an unknown
    wire or a CAN suffix python-can cannot write, ``OSError`` when the file cannot be created.
    """
    if wire == "serial":
        return JsonlFrameLog(Path(path), schema=schema, lazy=lazy)
    if wire == "can":
        return CanFrameLog(Path(path), channel=channel)
    raise ValueError(f"no frame log for wire {wire!r} (one of {', '.join(WIRES)})")
