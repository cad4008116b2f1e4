"""A message is one declaration: the ``@message`` classes of protocol.messages, and every table derived from them."""

from __future__ import annotations

import dataclasses
from enum import IntEnum

import pytest

from protocol import codec as c
from protocol import messages as m
from protocol.can.layouts import can_layouts
from protocol.messages import MsgType
from protocol.wiretypes import DECLARED, U8, CanField, Sender, message, wire


def test_the_wire_is_the_one_it_was() -> None:
    # the schema hashes HELLO and CAPS carry: the declarations moved into the classes, the wire did not change
    assert c.WIRE_SCHEMA_16.hash == 0x1D7AD3A3
    assert c.WIRE_SCHEMA_32.hash == 0xA57E0DD6


def test_every_type_is_declared_once_and_the_tables_derive_from_it() -> None:
    assert set(DECLARED) == {int(t) for t in MsgType}
    assert c.MESSAGE_CLASSES == {t: DECLARED[int(t)].cls for t in MsgType}
    assert m.HOST_TO_BOARD == {t for t in MsgType if DECLARED[int(t)].sender is not Sender.BOARD}
    assert m.BOARD_TO_HOST == {t for t in MsgType if DECLARED[int(t)].sender is Sender.BOARD}
    assert set(c.CAN_FIXED) == {t for t in MsgType if DECLARED[int(t)].can_fixed}
    for schema in c.WIRE_SCHEMAS:
        for t, layout in schema.layouts.items():
            assert [n for n, _ in layout] == [f.name for f in dataclasses.fields(c.MESSAGE_CLASSES[t])]
    # a per-schema field takes the schema's servo bound: the u16 mask up to 16 servos, the u32 one above
    assert c.WIRE_SCHEMA_16.layouts[MsgType.SERVO_FRAME][1][1].wire == "mask16[max=16]"
    assert c.WIRE_SCHEMA_32.layouts[MsgType.SERVO_FRAME][1][1].wire == "mask32[max=32]"


def test_a_fields_can_form_reaches_the_can_signals() -> None:
    assert c.CAN_FIXED[MsgType.TELEMETRY]["late_count"] == CanField(bits=24, clamped=True)
    signals = {s.name: s for cf in can_layouts(12).fields[MsgType.TELEMETRY] for s in cf.signals}
    assert signals["late_count"].bits == 24
    assert [k for k in signals if k.startswith("position_")] == [f"position_{i:02d}" for i in range(1, 13)]


def test_the_reference_directions_are_the_declared_senders() -> None:
    from protocol.wire_tables import DIRECTION

    assert DIRECTION[MsgType.HEARTBEAT] == "both"
    assert DIRECTION[MsgType.CAPS] == "board → host"
    assert DIRECTION[MsgType.SERVO_FRAME] == "host → board"


class _Spare(IntEnum):
    SPARE = 0xEE


def test_a_declaration_refuses_what_no_codec_could_derive() -> None:
    before = dict(DECLARED)
    with pytest.raises(ValueError, match="declared twice"):
        @message(MsgType.HELLO, Sender.HOST)
        class Again:
            x: int = wire(U8)
    with pytest.raises(ValueError, match=r"Bare\.x: declare it with wire"):
        @message(_Spare.SPARE, Sender.HOST)
        class Bare:
            x: int
    with pytest.raises(ValueError, match="ISO-TP bulk"):
        @message(_Spare.SPARE, Sender.HOST)
        class BulkWithCanForm:
            x: int = wire(U8, can=CanField(bits=4))
    assert DECLARED == before  # a refused declaration registers nothing
