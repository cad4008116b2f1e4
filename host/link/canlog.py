"""Read CAN frame logs (python-can formats: ``.log`` candump, ``.asc``, ``.blf``, ...) as protocol messages.

``iter_can_log(path)`` yields one :class:`CanLogEntry` per frame, in file order: the frame, its
direction (from the function code: ``h>b`` host to board, ``b>h`` board to host), its DBC view
(cantools, :data:`protocol.can` DBCs ``coco.dbc`` / ``coco_fd.dbc``: message name and raw signal
values; None for a frame the DBC does not know) and, when the frame completes one, the message
(fixed layouts reassembled by :class:`protocol.can.CanDecoder`, bulk by ISO-TP in listen mode) or
the decode error. Any number of nodes may share a capture (a decoder pair per node seen).
Used by ``ghostshell log decode`` and ``ghostshell replay``.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import can
import cantools

from protocol.can import CanDecodeError, CanDecoder, CanFrame, CanItem
from protocol.can.ids import BROADCAST_NODE, HOST_TO_BOARD, FunctionCode, bulk_ids, split_id
from protocol.can.isotp_link import IsoTpLink
from protocol.messages import Message, SimState

__all__ = ["CAN_LOG_SUFFIXES", "CanLogEntry", "can_last_sim_state", "candump_problem", "iter_can_log",
           "read_can_host_to_board"]

#: a candump -L line: "(1700000000.123456) vcan0 123#DEADBEEF" (CAN FD: ID##F DATA; remote: ID#R)
_CANDUMP_LINE = re.compile(r"^\(\d+(\.\d+)?\)\s+\S+\s+[0-9A-Fa-f]{1,8}#")


def candump_problem(path: str | Path) -> str | None:
    """Why ``path`` (a ``.log``) is not a candump ``-L`` log python-can reads (one line naming the first
    bad line), or None. python-can's reader fails on such a line with an unpacking error that names
    neither the file nor the line ("not enough values to unpack (expected 3, got 1)")."""
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            for lineno, line in enumerate(f, 1):
                text = line.strip()
                if text and not text.startswith("#") and not _CANDUMP_LINE.match(text):
                    return (f"{path}:{lineno} is not a candump -L line (expected '(TIMESTAMP) CHANNEL ID#DATA'): "
                            f"{text[:60]!r}")
    except OSError as e:
        return f"cannot read {path}: {e.strerror or e}"
    return None

#: suffixes python-can reads (can.LogReader) that a CAN run may be logged in
CAN_LOG_SUFFIXES = (".log", ".asc", ".blf", ".csv", ".trc", ".mf4")
PROTOCOL_DIR = Path(__file__).resolve().parents[2] / "protocol"


@lru_cache(maxsize=2)
def load_dbc(fd: bool) -> Any:
    """The checked-in DBC (classic or FD) as a cantools database."""
    return cantools.database.load_file(str(PROTOCOL_DIR / ("coco_fd.dbc" if fd else "coco.dbc")))


@dataclass
class CanLogEntry:
    t: float
    direction: str  # "h>b" | "b>h" | "?" (an identifier the protocol does not assign)
    frame: CanFrame
    dbc_name: str | None = None
    signals: dict[str, Any] = field(default_factory=dict)
    items: list[CanItem | CanDecodeError] = field(default_factory=list)


class _Node:
    def __init__(self, node: int, fd: bool) -> None:
        self.to_board = CanDecoder(node, "board")
        self.to_host = CanDecoder(node, "host")
        b, h = bulk_ids(node)
        self.bulk_board = IsoTpLink(rxid=b, txid=h, fd=fd, send=lambda f: None, listen=True)
        self.bulk_host = IsoTpLink(rxid=h, txid=b, fd=fd, send=lambda f: None, listen=True)


def iter_can_log(path: str | Path, *, dbc: bool = True) -> Iterator[CanLogEntry]:
    """Entries of a python-can log (see the module docstring); ``ValueError`` for an unknown format.

    ``dbc=False`` skips the DBC view (``dbc_name`` None, ``signals`` empty): several times faster
    for readers that need only the reassembled messages (``items``)."""
    nodes: dict[int, _Node] = {}
    for msg in can.LogReader(str(path)):  # type: ignore[no-untyped-call]
        if msg.is_error_frame:
            continue
        frame = CanFrame(int(msg.arbitration_id), bytes(msg.data or b""), bool(msg.is_fd),
                         bool(msg.is_extended_id), bool(msg.is_remote_frame))
        fn, node = split_id(frame.arbitration_id)
        direction = "?" if fn is None or frame.is_extended_id else ("h>b" if fn in HOST_TO_BOARD else "b>h")
        entry = CanLogEntry(float(msg.timestamp), direction, frame)
        if dbc and not frame.is_extended_id:
            try:
                dm = load_dbc(frame.is_fd).get_message_by_frame_id(frame.arbitration_id)
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
            st = nodes[node] = _Node(node, frame.is_fd)
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
