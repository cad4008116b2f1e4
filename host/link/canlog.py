"""Read CAN frame logs (python-can formats: ``.log`` candump, ``.asc``, ``.blf``, ...) as protocol messages.

``iter_can_log(path)`` yields one :class:`CanLogEntry` per frame, in file order: the frame, its
direction (from the function code: ``h>b`` host to board, ``b>h`` board to host), its DBC view
(cantools, the robot's DBC generated from its layouts, :mod:`protocol.can.make_dbc`, nodes 1 and 2:
message name and raw signal values; None for a frame the DBC does not know) and, when the frame
completes one, the message (fixed layouts reassembled by :class:`protocol.can.CanDecoder`, bulk by
ISO-TP in listen mode) or the decode error. Any number of nodes may share a capture (a decoder pair
per node seen). Used by ``ghostshell log decode`` and ``ghostshell replay``.

Which robot: the fixed layouts depend on the robot's servo count. ``servos`` names it; without it
the capture says itself: the servo count of its first CAPS (a bulk message whose layout is the same
for every robot; :func:`log_servo_count` finds it), else
:data:`protocol.can.layouts.DEFAULT_SERVO_COUNT`.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import can

from protocol.can import CanDecodeError, CanDecoder, CanFrame, CanItem
from protocol.can.codec import decode_bulk
from protocol.can.ids import BROADCAST_NODE, HOST_TO_BOARD, FunctionCode, bulk_ids, split_id
from protocol.can.isotp_link import IsoTpLink
from protocol.can.layouts import DEFAULT_SERVO_COUNT, CanLayouts, can_layouts
from protocol.codec import PayloadError
from protocol.messages import MAX_WIRE_SERVOS, Caps, Message, SimState

__all__ = ["CAN_LOG_SUFFIXES", "CanLogEntry", "CanLogError", "can_last_sim_state", "candump_cut_line", "candump_problem", "is_candump", "iter_can_log", "load_dbc",
           "log_servo_count", "read_can_host_to_board"]

#: a candump -L line: "(1700000000.123456) vcan0 123#DEADBEEF" (CAN FD: ID##F DATA; remote: ID#R)
_CANDUMP_LINE = re.compile(r"^\(\d+(\.\d+)?\)\s+\S+\s+[0-9A-Fa-f]{1,8}#")
#: characters a candump -L line of one frame can have: a CAN FD frame's 64 data bytes are 128 hex digits,
#: with the time stamp, an interface name (at most 15 characters, IFNAMSIZ), a 29-bit id, ``##`` and its flag
#: digit and a direction mark that is under 200; longer is no frame (a new user's 25 MB line was taken as one)
CANDUMP_MAX_LINE = 256


def _is_cut(line: str) -> bool:
    """A file's last line that a logger stopped in the middle of: text with no newline at its end (candump
    and python-can's writer end every line with one; a line cut inside its data can still look whole)."""
    return not line.endswith("\n") and bool(line.strip())


class _WholeLines:
    """A candump text file's lines, without a last line cut off mid-frame (``cut_line``: its number, once
    iterated; None when there was none). A logger killed while writing (``kill -9``, a power cut) leaves
    such a line; python-can's reader fails on it and with it on the whole capture."""

    def __init__(self, path: str | Path) -> None:
        self.file = open(path, encoding="utf-8", errors="replace")  # noqa: SIM115 - closed by close()
        self.cut_line: int | None = None

    def __iter__(self) -> Iterator[str]:
        for lineno, line in enumerate(self.file, 1):
            if _is_cut(line):
                self.cut_line = lineno
                return
            yield line

    def close(self) -> None:
        self.file.close()


def candump_cut_line(path: str | Path) -> int | None:
    """The number of a ``.log``'s last line when a logger stopped in the middle of it (skipped by the
    readers here, :func:`iter_can_log`), or None."""
    lines = _WholeLines(path)
    try:
        for _ in lines:
            pass
    finally:
        lines.close()
    return lines.cut_line


def is_candump(path: str | Path) -> bool:
    """Whether ``path`` is read as candump ``-L`` text: a ``.log``, or a name with no suffix python-can
    reads (``log decode FILE --link can:…`` of a capture saved as ``capture.txt``)."""
    name = str(path).lower()
    return name.endswith(".log") or not name.endswith(CAN_LOG_SUFFIXES)


class CanLogError(ValueError):
    """A file python-can cannot read as a CAN log (damaged, not that format, or its reader's optional
    package missing); the message names the file and says why, on one line."""


class _Quiet(logging.Handler):
    """Keeps python-can's reader warnings ("can.io.trc: ...") off stderr while a log is read; the first
    one is kept to explain a failure."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.first: str | None = None

    def emit(self, record: logging.LogRecord) -> None:
        if self.first is None:
            self.first = record.getMessage().splitlines()[0][:200] if record.getMessage() else None


def _reader(path: str | Path) -> Iterator[Any]:
    """python-can's messages of ``path`` (reader by suffix); candump text (:func:`is_candump`) without a
    cut-off last line. Any failure of python-can's reader (``struct.error`` from a damaged ``.blf``,
    ``BLFParseError``, ``UnicodeDecodeError``, a missing ``asammdf`` for ``.mf4``, ...) is a
    :class:`CanLogError`; its logging warnings do not reach the root logger's handlers (stderr)."""
    log = logging.getLogger("can")
    quiet = _Quiet()
    was_propagating = log.propagate
    log.addHandler(quiet)
    log.propagate = False
    reader: Any = None
    try:
        try:
            if is_candump(path):
                reader = can.CanutilsLogReader(_WholeLines(path))  # type: ignore[arg-type]
            else:
                reader = can.LogReader(str(path))  # type: ignore[no-untyped-call]
            it = iter(reader)
            while True:
                try:
                    msg = next(it)
                except StopIteration:
                    return
                yield msg
        except FileNotFoundError:
            raise CanLogError(f"cannot read {path}: no such file") from None
        except IsADirectoryError:
            raise CanLogError(f"cannot read {path}: it is a folder; give a CAN log file") from None
        except NotImplementedError as e:  # python-can's MF4Reader without asammdf
            raise CanLogError(f"cannot read {path}: python-can needs an optional package for this format "
                              f"({str(e).splitlines()[0] if str(e) else type(e).__name__})") from None
        except Exception as e:  # noqa: BLE001 - python-can's readers raise struct.error, BLFParseError, ...
            detail = str(e).splitlines()[0][:200] if str(e) else ""
            if quiet.first:
                detail = f"{detail}; {quiet.first}" if detail else quiet.first
            raise CanLogError(f"cannot read {path} as a {Path(path).suffix or 'CAN'} log "
                              f"({type(e).__name__}{': ' + detail if detail else ''})") from None
    finally:
        log.removeHandler(quiet)
        log.propagate = was_propagating
        if reader is not None:
            try:
                reader.stop()
            except Exception:  # noqa: BLE001 - a reader that failed to open may have nothing to close
                pass


def candump_problem(path: str | Path) -> str | None:
    """Why ``path`` (a ``.log``) is not a candump ``-L`` log python-can reads (one line naming the first
    bad line), or None. python-can's reader fails on such a line with an unpacking error that names
    neither the file nor the line ("not enough values to unpack (expected 3, got 1)"). A last line cut
    off mid-frame is no problem: the readers here skip it (:func:`candump_cut_line`)."""
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            for lineno, line in enumerate(f, 1):
                if _is_cut(line):
                    break  # the last line (no newline after it)
                text = line.strip()
                if len(text) > CANDUMP_MAX_LINE:
                    return (f"{path}:{lineno} is not a candump -L line: {len(text)} characters, more than one CAN "
                            f"frame's line can have ({CANDUMP_MAX_LINE})")
                if text and not text.startswith("#") and not _CANDUMP_LINE.match(text):
                    return (f"{path}:{lineno} is not a candump -L line (expected '(TIMESTAMP) CHANNEL ID#DATA'): "
                            f"{text[:60]!r}")
    except OSError as e:
        return f"cannot read {path}: {e.strerror or e}"
    return None

#: suffixes python-can reads (can.LogReader) that a CAN run may be logged in
CAN_LOG_SUFFIXES = (".log", ".asc", ".blf", ".csv", ".trc", ".mf4")


@lru_cache(maxsize=8)
def load_dbc(fd: bool, servos: int = DEFAULT_SERVO_COUNT) -> Any:
    """The DBC (classic or FD) of a robot of ``servos`` servos as a cantools database (generated from
    the layouts; the robot's name and title only appear in comments, so any name does)."""
    from protocol.can.make_dbc import DbcRobot, build_database

    return build_database(fd, robot=DbcRobot("robot", "Robot", servos))


def log_servo_count(path: str | Path) -> int | None:
    """The servo count the first CAPS in a CAN capture reports (None: the capture holds no CAPS).
    Reads only up to that CAPS; :class:`CanLogError` for a file python-can cannot read."""
    bulk: dict[int, IsoTpLink] = {}
    for msg in _reader(path):
        if msg.is_error_frame or msg.is_extended_id:
            continue
        fn, node = split_id(int(msg.arbitration_id))
        data = bytes(msg.data or b"")
        if fn is not FunctionCode.BULK_TO_HOST or node is None or (data[:1] and data[0] >> 4 == 3):
            continue
        link = bulk.get(node)
        if link is None:
            b, h = bulk_ids(node)
            link = bulk[node] = IsoTpLink(rxid=h, txid=b, fd=bool(msg.is_fd), send=lambda f: None, listen=True)
        link.feed(CanFrame(int(msg.arbitration_id), data, bool(msg.is_fd)))
        for sdu in link.poll():
            try:
                _, m = decode_bulk(sdu)  # CAPS has the same layout in every wire schema
            except PayloadError:
                continue
            if isinstance(m, Caps) and 1 <= m.servo_count <= MAX_WIRE_SERVOS:
                return int(m.servo_count)
    return None


@dataclass
class CanLogEntry:
    t: float
    direction: str  # "h>b" | "b>h" | "?" (an identifier the protocol does not assign)
    frame: CanFrame
    dbc_name: str | None = None
    signals: dict[str, Any] = field(default_factory=dict)
    items: list[CanItem | CanDecodeError] = field(default_factory=list)


class _Node:
    def __init__(self, node: int, fd: bool, layouts: CanLayouts) -> None:
        self.to_board = CanDecoder(node, "board", layouts)
        self.to_host = CanDecoder(node, "host", layouts)
        b, h = bulk_ids(node)
        self.bulk_board = IsoTpLink(rxid=b, txid=h, fd=fd, send=lambda f: None, listen=True)
        self.bulk_host = IsoTpLink(rxid=h, txid=b, fd=fd, send=lambda f: None, listen=True)


def iter_can_log(path: str | Path, *, dbc: bool = True, servos: int | None = None) -> Iterator[CanLogEntry]:
    """Entries of a python-can log (see the module docstring); :class:`CanLogError` (a ``ValueError``)
    for an unknown format or a file python-can cannot read.

    ``dbc=False`` skips the DBC view (``dbc_name`` None, ``signals`` empty): several times faster
    for readers that need only the reassembled messages (``items``). ``servos``: the robot's servo
    count (default: the capture's first CAPS says, else :data:`DEFAULT_SERVO_COUNT`)."""
    servo_count = servos if servos is not None else (log_servo_count(path) or DEFAULT_SERVO_COUNT)
    layouts = can_layouts(servo_count)
    nodes: dict[int, _Node] = {}
    for msg in _reader(path):
        if msg.is_error_frame:
            continue
        frame = CanFrame(int(msg.arbitration_id), bytes(msg.data or b""), bool(msg.is_fd),
                         bool(msg.is_extended_id), bool(msg.is_remote_frame))
        fn, node = split_id(frame.arbitration_id)
        direction = "?" if fn is None or frame.is_extended_id else ("h>b" if fn in HOST_TO_BOARD else "b>h")
        entry = CanLogEntry(float(msg.timestamp), direction, frame)
        if dbc and not frame.is_extended_id:
            try:
                dm = load_dbc(frame.is_fd, servo_count).get_message_by_frame_id(frame.arbitration_id)
                entry.dbc_name = dm.name
                entry.signals = dm.decode(frame.data, decode_choices=False, scaling=False, allow_truncated=True)
            except Exception:  # not in the DBC, or data the DBC cannot decode: no DBC view
                entry.dbc_name = None
                entry.signals = {}
        if fn is None or frame.is_extended_id:
            yield entry
            continue
        if node == BROADCAST_NODE:
            targets = list(nodes.values()) or []
            for n in targets:
                entry.items += n.to_board.feed(frame)
            yield entry
            continue
        st = nodes.get(node)
        if st is None:
            st = nodes[node] = _Node(node, frame.is_fd, layouts)
        if fn in (FunctionCode.BULK_TO_BOARD, FunctionCode.BULK_TO_HOST) and frame.data[:1] and frame.data[0] >> 4 == 3:
            yield entry  # ISO-TP flow control: for the other direction's sender, nothing to reassemble
            continue
        if fn is FunctionCode.BULK_TO_BOARD:
            st.bulk_board.feed(frame)
            entry.items += [st.to_board.feed_bulk(sdu) for sdu in st.bulk_board.poll()]
        elif fn is FunctionCode.BULK_TO_HOST:
            st.bulk_host.feed(frame)
            entry.items += [st.to_host.feed_bulk(sdu) for sdu in st.bulk_host.poll()]
        elif fn in HOST_TO_BOARD:
            entry.items += st.to_board.feed(frame)
        else:
            entry.items += st.to_host.feed(frame)
        yield entry


def read_can_host_to_board(path: Path) -> Iterator[tuple[float, int, Message]]:
    """``(t, seq, message)`` the host sent to its board (the first node seen), in order."""
    first: int | None = None
    for e in iter_can_log(path, dbc=False):
        if e.direction != "h>b":
            continue
        node = split_id(e.frame.arbitration_id)[1]
        if first is None and node != BROADCAST_NODE:
            first = node
        if node not in (first, BROADCAST_NODE):
            continue
        for it in e.items:
            if isinstance(it, CanItem):
                yield e.t, it.seq, it.msg


def can_last_sim_state(path: Path) -> SimState | None:
    """The last SIM_STATE the board sent in the capture (the recording host's final ground truth)."""
    last: SimState | None = None
    for e in iter_can_log(path, dbc=False):
        if e.direction == "b>h":
            for it in e.items:
                if isinstance(it, CanItem) and isinstance(it.msg, SimState):
                    last = it.msg
    return last
