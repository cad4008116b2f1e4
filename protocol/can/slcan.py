"""SLCAN (Lawicel ASCII) as sans-I/O engines: bytes in -> lines / frames out, frames in -> lines out.

Shared by both ends: :class:`LineSplitter` cuts a byte stream into bounded lines (the adapter's
command lines, the host's response lines); :func:`format_frame` is the one place a frame becomes
a ``t``/``T``/``r``/``R``/``d``/``D``/``b``/``B`` line (the board announcing a received frame to
the host, the host's non-blocking output to an adapter: the same lines python-can's
``slcanBus.send`` writes); :class:`SlcanDevice` is the adapter's firmware side, the state machine
the emulated board runs on its pty. No I/O here: the board's SLCAN transport and the host's
:mod:`host.link.transports.slcan_tx` / ``slcan_rx`` move the bytes.

The device side is hand-written because python-can (and every maintained package we know of)
implements only the *host* side of SLCAN (``can.interfaces.slcan``); an adapter's firmware side is
exactly what the emulated board has to be here. The host keeps python-can's parser
(``slcanBus._recv_internal``) and uses :class:`LineSplitter` only to read whole lines at once.

The dialect is the one python-can's ``slcan`` interface speaks
(Lawicel CANUSB manual + the common FD extension): commands end with ``\\r``; an accepted command
is answered ``\\r``, a refused one with BEL (``\\a``).

=========  =====================================================  ===================
command    meaning                                                answer
=========  =====================================================  ===================
``O``      open the channel (``L``: listen only)                  ``\\r``
``C``      close the channel                                      ``\\r``
``Sn``     bitrate code 0..8 (10 k .. 1 M), ``Yn`` FD data rate   ``\\r`` (closed only)
``sXXYY``  BTR0/BTR1 registers                                    ``\\r`` (closed only)
``V``      version                                                ``V1013\\r``
``N``      serial number                                          ``NGHST\\r``
``F``      status flags                                           ``F00\\r``
``tIIIL..`` standard frame, ``T`` extended, ``r``/``R`` remote    ``z\\r`` / ``Z\\r``
``dIIIL..`` FD frame (L = FD DLC hex), ``D`` ext., ``b``/``B`` BRS  ``z\\r`` / ``Z\\r``
=========  =====================================================  ===================

Frames to the host go out as the same ``t``/``d`` lines. Lines are bounded (``MAX_LINE``): a
longer run without ``\\r`` is dropped and counted; a malformed line is counted and answered BEL.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from protocol.can.frame import FD_LENGTHS, CanFrame

__all__ = ["MAX_LINE", "LineSplitter", "SlcanDevice", "SlcanEvent", "format_frame"]

MAX_LINE = 1 + 8 + 1 + 2 * 64 + 8  # longest valid line (extended FD frame) plus slack
OK = b"\r"
BELL = b"\a"
_HEX = frozenset("0123456789abcdefABCDEF")


@dataclass(frozen=True)
class SlcanEvent:
    """A parsed line: ``frame`` set for a frame, else ``command`` (the letter); ``error`` if refused."""

    frame: CanFrame | None = None
    command: str = ""
    error: str = ""


def format_frame(frame: CanFrame, *, brs: bool = False) -> bytes:
    """The SLCAN line (``\\r`` included) for ``frame``: what an adapter prints for a frame it received,
    and what a host writes to send one (python-can's ``slcanBus.send`` builds the same text). FD
    frames: ``d``/``D`` (``b``/``B`` with ``brs``, bit-rate switch), the length as the FD DLC in hex
    (``ValueError`` for a length no FD frame has)."""
    n = len(frame.data)
    if frame.is_fd:
        dlc = FD_LENGTHS.index(n)
        letter = "b" if brs else "d"
        head = f"{letter.upper()}{frame.arbitration_id:08X}" if frame.is_extended_id else f"{letter}{frame.arbitration_id:03X}"
        return f"{head}{dlc:X}{frame.data.hex().upper()}\r".encode()
    if frame.is_remote:
        head = f"R{frame.arbitration_id:08X}" if frame.is_extended_id else f"r{frame.arbitration_id:03X}"
        return f"{head}{n:d}\r".encode()
    head = f"T{frame.arbitration_id:08X}" if frame.is_extended_id else f"t{frame.arbitration_id:03X}"
    return f"{head}{n:d}{frame.data.hex().upper()}\r".encode()


class LineSplitter:
    """Bytes in, whole lines out: ``feed(data) -> [(line, terminator)]``; never raises, bounded.

    A line ends at any byte of ``terminators`` (the terminator is returned apart, not in the
    line). A run of more than ``max_line`` bytes without a terminator is dropped (memory stays
    bounded) and reported once, at its terminator, as ``(None, terminator)``. ``pending`` is the
    partial line held for the next feed.
    """

    def __init__(self, terminators: bytes, max_line: int) -> None:
        self._ends = re.compile(b"[" + re.escape(terminators) + b"]")
        self.max_line = max_line
        self.pending = bytearray()
        self._overlong = False

    def feed(self, data: bytes) -> list[tuple[bytes | None, int]]:
        out: list[tuple[bytes | None, int]] = []
        start = 0
        for m in self._ends.finditer(data):
            end = m.start()
            if self._overlong or len(self.pending) + end - start > self.max_line:
                out.append((None, data[end]))
            else:
                out.append((bytes(self.pending + data[start:end]) if self.pending else bytes(data[start:end]), data[end]))
            self.pending.clear()
            self._overlong = False
            start = end + 1
        if start < len(data) and not self._overlong:
            self.pending += data[start:]
            if len(self.pending) > self.max_line:
                self._overlong = True
                self.pending.clear()
        return out


class SlcanDevice:
    """The adapter's state machine: ``feed(bytes) -> (events, reply bytes)``; never raises."""

    def __init__(self) -> None:
        self.is_open = False
        self.bitrate_code = "S8"
        self._lines = LineSplitter(b"\r\n", MAX_LINE)
        self.errors = 0
        self.frames_in = 0

    @property
    def _line(self) -> bytearray:
        """The partial line held for the next feed (at most ``MAX_LINE`` bytes)."""
        return self._lines.pending

    def feed(self, data: bytes) -> tuple[list[SlcanEvent], bytes]:
        events: list[SlcanEvent] = []
        reply = bytearray()
        for line, end in self._lines.feed(data):
            if line is None:  # \r ends a line (\n tolerated); an over-long one is refused
                self.errors += 1
                events.append(SlcanEvent(error=f"line longer than {MAX_LINE} characters"))
                reply += BELL
            elif line or end == 0x0D:  # an empty line ended by \n alone is nothing
                ev, ans = self._line_done(line)
                events.append(ev)
                reply += ans
        return events, bytes(reply)

    def _bad(self, why: str) -> tuple[SlcanEvent, bytes]:
        self.errors += 1
        return SlcanEvent(error=why), BELL

    def _line_done(self, raw: bytes) -> tuple[SlcanEvent, bytes]:
        try:
            line = raw.decode("ascii")
        except UnicodeDecodeError:
            return self._bad("non-ASCII line")
        if not line:
            return SlcanEvent(command=""), OK  # empty command (python-can sends one): accepted
        c = line[0]
        if c in "OL":
            self.is_open = True
            return SlcanEvent(command=c), OK
        if c == "C":
            self.is_open = False
            return SlcanEvent(command=c), OK
        if c == "S" and len(line) == 2 and line[1] in "012345678":
            if self.is_open:
                return self._bad("bitrate change while open")
            self.bitrate_code = line
            return SlcanEvent(command=c), OK
        if c == "Y" and len(line) == 2 and line[1] in "25":
            return SlcanEvent(command=c), OK
        if c == "s" and len(line) == 5 and set(line[1:]) <= _HEX:
            return SlcanEvent(command=c), OK
        if c == "V" and len(line) == 1:
            return SlcanEvent(command=c), b"V1013\r"
        if c == "N" and len(line) == 1:
            return SlcanEvent(command=c), b"NGHST\r"
        if c == "F" and len(line) == 1:
            return SlcanEvent(command=c), b"F00\r"
        if c in "tTrRdDbB":
            return self._frame(line)
        return self._bad(f"unknown command {line[:12]!r}")

    def _frame(self, line: str) -> tuple[SlcanEvent, bytes]:
        c = line[0]
        ext = c in "TRDB"
        fd = c in "dDbB"
        remote = c in "rR"
        id_len = 8 if ext else 3
        if len(line) < 1 + id_len + 1:
            return self._bad(f"frame line too short: {line!r}")
        id_text, dlc_text, data_text = line[1 : 1 + id_len], line[1 + id_len], line[2 + id_len :]
        if not (set(id_text) <= _HEX and dlc_text in _HEX and set(data_text) <= _HEX):
            return self._bad(f"frame line is not hex: {line[:24]!r}")
        aid = int(id_text, 16)
        if aid > (0x1FFFFFFF if ext else 0x7FF):
            return self._bad(f"identifier {id_text} out of range")
        dlc = int(dlc_text, 16)
        if fd:
            n = FD_LENGTHS[dlc]
        elif dlc > 8:
            return self._bad(f"classic DLC {dlc} > 8")
        else:
            n = dlc
        if remote:
            if data_text:
                return self._bad("remote frame with data")
            data = b""
        else:
            if len(data_text) != 2 * n:
                return self._bad(f"DLC {dlc} needs {n} data bytes, line has {len(data_text) // 2}")
            data = bytes.fromhex(data_text)
        if not self.is_open:
            return self._bad("frame while the channel is closed (send O first)")
        self.frames_in += 1
        frame = CanFrame(aid, data, is_fd=fd, is_extended_id=ext, is_remote=remote)
        return SlcanEvent(frame=frame, command=c), (b"Z\r" if ext else b"z\r")
