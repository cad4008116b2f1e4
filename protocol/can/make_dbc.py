"""A robot's DBC (classic CAN or CAN FD) from its layouts: :func:`build_database`, :func:`dbc_text`.

``dbc_text(fd, nodes, robot=DbcRobot(name, title, servos))`` builds a cantools database from the
robot's layout table (:func:`protocol.can.layouts.can_layouts`): one DBC message per fixed-layout
function code and node (``SERVO_FRAME_N1`` = 0x081 ...), plus the broadcast ``ESTOP_ALL`` (0x000).
A multi-part message is a multiplexed DBC message: the 5-bit ``part`` signal is the multiplexer
and every other signal belongs to the part it is placed in. The ISO-TP (bulk) identifiers are in the DBC as opaque frames
(PCI nibbles + bytes: their content is the serial payload codec, reassembled by ISO-TP), so a
capture has no unknown frames. A message the robot's table sends as bulk in that frame kind
(classic TELEMETRY above 27 servos) has no DBC message of its own. The text names the robot only in
the database version (``NAME-1``, 1 = the protocol version) and the board nodes' comments
(``TITLE board, node id N``); the rest comes from the layouts.

``ghostshell dbc --robot NAME [--fd] [--nodes 1,2]`` prints a robot's DBC; built-in robots may check
theirs in next to their robot.toml as ``NAME.dbc`` and ``NAME_fd.dbc``, which ``ghostshell dbc --robot
NAME --check`` compares and ``--write`` rewrites (:mod:`host.commands.dbc`: finding robots is the
host's business; ``protocol`` imports no robot). Without a robot,
``python -m protocol.can.make_dbc --servos N [--fd] [--nodes 1,2] [--name NAME] [--title TITLE]``
prints the DBC of a robot of N servos (exit 2 with one line for bad arguments).

This is the only module of ``protocol`` that imports cantools (it is a build tool, not runtime).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass

import cantools
from cantools.database.can import Database, Message, Node, Signal
from cantools.database.conversion import BaseConversion

from protocol.can.ids import BROADCAST_NODE, BOARD_TO_HOST, FunctionCode, cob_id
from protocol.can.layouts import PART_BITS, SEQ_BITS, FixedLayout, can_layouts
from protocol.messages import PROTOCOL_VERSION

__all__ = ["CYCLE_MS", "DbcRobot", "build_database", "dbc_text", "main"]

DEFAULT_NODES = (1, 2)
#: Nominal periods (ms) at the default rates: servo frames 100 Hz, telemetry 50 Hz, heartbeats 50 ms.
CYCLE_MS = {
    FunctionCode.SERVO_FRAME: 10,
    FunctionCode.TELEMETRY: 20,
    FunctionCode.HEARTBEAT_HOST: 50,
    FunctionCode.TIME_SYNC_REQUEST: 500,
    FunctionCode.TIME_SYNC_REPLY: 500,
}
HOST = "HOST"


@dataclass(frozen=True)
class DbcRobot:
    """What a DBC says about its robot: ``name`` (the database version ``NAME-1``), ``title`` (the
    board nodes' comments) and ``servos`` (the layout table)."""

    name: str
    title: str
    servos: int


def _board(node: int) -> str:
    return f"BOARD_{node}"


def _signals(layout: FixedLayout, receiver: str) -> list[Signal]:
    multi = layout.parts > 1
    sigs = [
        Signal(
            "part",
            0,
            PART_BITS,
            is_multiplexer=multi,
            comment="index of this frame among the message's parts",
            receivers=[receiver],
        ),
        Signal("seq", PART_BITS, SEQ_BITS, comment="protocol sequence number modulo 2**11", receivers=[receiver]),
    ]
    for p in layout.signals:
        s = p.spec
        lo, hi = (-(1 << (s.bits - 1)), (1 << (s.bits - 1)) - 1) if s.signed else (0, (1 << s.bits) - 1)
        sigs.append(
            Signal(
                s.name,
                p.start,
                s.bits,
                is_signed=s.signed,
                conversion=BaseConversion.factory(scale=s.scale, offset=0, is_float=False),
                minimum=lo * s.scale,
                maximum=hi * s.scale,
                unit=s.unit or None,
                comment=s.comment or None,
                multiplexer_ids=[p.part] if multi else None,
                multiplexer_signal="part" if multi else None,
                receivers=[receiver],
            )
        )
    return sigs


def _bulk_message(fn: FunctionCode, node: int, fd: bool, sender: str, receiver: str) -> Message:
    """An ISO-TP frame: the protocol control information (PCI) nibble, then opaque bytes."""
    length = 64 if fd else 8
    sigs = [
        Signal("isotp_pci_type", 4, 4, comment="ISO 15765-2 PCI: 0 single, 1 first, 2 consecutive, 3 flow control",
               receivers=[receiver]),
        Signal("isotp_pci_low", 0, 4, comment="SF length / FF length high nibble / CF index / FC status",
               receivers=[receiver]),
    ]
    for i in range(1, min(length, 8)):
        sigs.append(Signal(f"isotp_byte_{i}", 8 * i, 8, receivers=[receiver]))
    return Message(
        cob_id(fn, node),
        f"{fn.name}_N{node}",
        length,
        sigs,
        senders=[sender],
        comment="ISO-TP (ISO 15765-2) segment of a bulk message: type u8, seq u16, protocol.codec payload"
        + (" (padded to 64 bytes)" if fd else " (padded to 8 bytes)"),
        is_fd=fd,
    )


def build_database(fd: bool, nodes: tuple[int, ...] = DEFAULT_NODES, *, robot: DbcRobot) -> Database:
    """A cantools database of every fixed-layout message of ``robot`` for ``nodes`` (classic or FD)."""
    table = can_layouts(robot.servos)
    messages: list[Message] = []
    for node in nodes:
        for (fn, is_fd), layout in sorted(table.fixed.items(), key=lambda kv: int(kv[0][0])):
            if is_fd != fd:
                continue
            to_host = fn in BOARD_TO_HOST
            sender, receiver = (_board(node), HOST) if to_host else (HOST, _board(node))
            messages.append(
                Message(
                    cob_id(fn, node),
                    f"{fn.name}_N{node}",
                    layout.length,
                    _signals(layout, receiver),
                    senders=[sender],
                    cycle_time=CYCLE_MS.get(fn),
                    comment=f"{layout.msg_type.name}, {layout.parts} part(s) tied by seq",
                    is_fd=fd,
                )
            )
    for node in nodes:
        for fn in (FunctionCode.BULK_TO_BOARD, FunctionCode.BULK_TO_HOST):
            to_host = fn is FunctionCode.BULK_TO_HOST
            sender, receiver = (_board(node), HOST) if to_host else (HOST, _board(node))
            messages.append(_bulk_message(fn, node, fd, sender, receiver))
    estop = table.fixed[(FunctionCode.ESTOP, fd)]
    messages.insert(
        0,
        Message(
            cob_id(FunctionCode.ESTOP, BROADCAST_NODE),
            "ESTOP_ALL",
            estop.length,
            _signals(estop, _board(nodes[0])),
            senders=[HOST],
            comment="broadcast emergency stop: every board holds",
            is_fd=fd,
        ),
    )
    node_list = [Node(HOST, comment="GhostShell host")] + [Node(_board(n), comment=f"{robot.title} board, node id {n}")
                                                     for n in nodes]
    # start from a skeleton that carries the BusType attribute: cantools marks FD frames
    # (VFrameFormat StandardCAN_FD) only on a bus declared "CAN FD"
    db = cantools.database.load_string(_SKELETON.format(bus="CAN FD" if fd else "CAN"), database_format="dbc")
    assert isinstance(db, Database)
    db.version = f"{robot.name}-{PROTOCOL_VERSION}"
    db.messages.extend(messages)
    db.nodes.extend(node_list)
    db.refresh()
    return db


_SKELETON = '''VERSION ""

NS_ :

BS_:

BU_:

BA_DEF_  "BusType" STRING ;
BA_DEF_DEF_  "BusType" "";
BA_ "BusType" "{bus}";
'''


def dbc_text(fd: bool, nodes: tuple[int, ...] = DEFAULT_NODES, *, robot: DbcRobot) -> str:
    """The DBC file text of ``robot`` (deterministic)."""
    return build_database(fd, nodes, robot=robot).as_dbc_string().replace("\r\n", "\n")


def main(argv: list[str] | None = None) -> int:
    """``python -m protocol.can.make_dbc --servos N ...``: print the DBC of a robot of N servos."""
    ap = argparse.ArgumentParser(prog="python -m protocol.can.make_dbc",
                                 description="print the DBC (classic CAN, or FD) of a robot of N servos")
    ap.add_argument("--servos", type=int, required=True, metavar="N", help="the robot's servo count (1..32)")
    ap.add_argument("--fd", action="store_true", help="the CAN FD database (default: classic CAN)")
    ap.add_argument("--nodes", default=",".join(map(str, DEFAULT_NODES)), help="node ids, comma-separated")
    ap.add_argument("--name", default="robot", help="the database version's robot name (default robot)")
    ap.add_argument("--title", default="Robot", help="the board nodes' comments say 'TITLE board' (default Robot)")
    args = ap.parse_args(argv)
    try:
        nodes = tuple(int(n) for n in args.nodes.split(","))
    except ValueError:
        ap.error(f"--nodes: expected comma-separated node ids, got {args.nodes!r}")
    try:
        text = dbc_text(args.fd, nodes, robot=DbcRobot(args.name, args.title, args.servos))
    except ValueError as e:  # a servo count the wire cannot carry, a node id out of range
        print(f"python -m protocol.can.make_dbc: {e}", file=sys.stderr)
        return 2
    try:
        sys.stdout.write(text)
        sys.stdout.flush()
    except BrokenPipeError:
        return 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
