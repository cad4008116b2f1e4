"""Generate the C firmware's CAN layout table (``gs_can_layouts.h``) for a robot of N servos.

The C CAN engine (``firmware_sim/c/core/gs_can.c``) packs and unpacks fixed-layout frames by a table,
never by hand-written layouts: this module turns :func:`protocol.can.layouts.can_layouts` (the layouts
derived from the one message declaration, the classes of :mod:`protocol.messages`)
into C99 text (pure: it returns a string; the firmware build, :mod:`firmware_sim.cfirmware.build`,
writes it into the build folder next to the servo table, as ``gs_servo_table.h``).

What the header holds (types in ``gs_can.h``):

* ``gs_can_fields_<msg>[]``: per fixed-layout message type, its serial fields in layout order with
  the CAN form of each (``gs_can_field_t``: one field-kind rule, the C member's offset in ``gs_msg_t``
  and width, the signal count and width, clamped / wrapping / omitted, the mask field driving a
  per-servo array, the enum members allowed) -- the rules :func:`protocol.can.codec.message_to_raw`
  and :func:`~protocol.can.codec.raw_to_message` apply by field kind;
* ``gs_can_layouts[]``: per (function code, frame kind) that has a fixed layout, its parts, frame
  length, bytes per part and every signal's (part, start bit, bits, signedness) in signal order
  (the fields' signals, then ``crc16``);
* ``GS_CAN_SERVOS`` (N), ``GS_CAN_MAX_SIGNALS``, ``GS_CAN_LAYOUT_COUNT``.

A field kind without a rule here fails generation naming it (as :mod:`protocol.cgen`), so a new
field kind in a fixed-layout message is one more entry in :data:`FIELD_KINDS`.
"""

from __future__ import annotations

from protocol.can.ids import FunctionCode
from protocol.can.layouts import CRC_SIGNAL, CarriedField, can_layouts
from protocol.codec import Bool, EnumU8, Field, Flags16, Mask, Q16Array, RestBytes, SInt, Str8, UInt
from protocol.messages import MsgType

__all__ = ["FIELD_KINDS", "can_layouts_h"]

#: field class -> the C rule name (``GS_CAN_K_*`` in gs_can.h)
FIELD_KINDS: dict[type[Field], str] = {
    UInt: "GS_CAN_K_UINT",
    SInt: "GS_CAN_K_SINT",
    Bool: "GS_CAN_K_BOOL",
    EnumU8: "GS_CAN_K_ENUM",
    Flags16: "GS_CAN_K_FLAGS",
    Mask: "GS_CAN_K_MASK",
    Str8: "GS_CAN_K_OMITTED",
    RestBytes: "GS_CAN_K_OMITTED",
}


def _q16_kind(f: Q16Array) -> str:
    if f.fixed is not None:
        return "GS_CAN_K_Q16_FIXED"
    return "GS_CAN_K_Q16_MASKED" if f.mask_field is not None else "GS_CAN_K_Q16_COUNTED"


def _member(t: MsgType, name: str) -> str:
    return f"u.{t.name.lower()}.{name}"


def _field_row(t: MsgType, cf: CarriedField, carried: tuple[CarriedField, ...], mask_bytes: int) -> str:
    f = cf.field
    names = [c.name for c in carried]
    if isinstance(f, Q16Array):
        kind = _q16_kind(f)
    elif type(f) in FIELD_KINDS:
        kind = FIELD_KINDS[type(f)]
    else:
        raise ValueError(f"{t.name}.{cf.name}: no C CAN rule for a {type(f).__name__} ({f.wire}); add one to "
                         "protocol.can.cgen.FIELD_KINDS and gs_can.c")
    if cf.form.omitted:
        kind = "GS_CAN_K_OMITTED"
    size = {"GS_CAN_K_BOOL": 1, "GS_CAN_K_ENUM": 1, "GS_CAN_K_FLAGS": 2, "GS_CAN_K_OMITTED": 1}.get(kind, 0)
    if isinstance(f, (UInt, SInt)):
        size = f.size
    elif isinstance(f, Mask):
        size = mask_bytes
    elif isinstance(f, Q16Array):
        size = 2
    count = "0"  # offset of the uint8_t count member (counted and masked arrays; omitted text/bytes: its length)
    if kind in ("GS_CAN_K_Q16_MASKED", "GS_CAN_K_Q16_COUNTED"):
        count = f"offsetof(gs_msg_t, {_member(t, cf.name + '_n')})"
    elif kind == "GS_CAN_K_OMITTED":
        count = f"offsetof(gs_msg_t, {_member(t, cf.name + '_len')})"
    flags = []
    if isinstance(f, UInt) and f.wrap and not cf.form.clamped:
        flags.append("GS_CAN_F_WRAP")
    if isinstance(f, Q16Array) and not f.allow_nan:
        flags.append("GS_CAN_F_NONAN")
    if isinstance(f, Mask) and any(isinstance(c.field, Q16Array) and c.field.mask_field == cf.name for c in carried):
        flags.append("GS_CAN_F_DRIVES")
    mask_index = names.index(f.mask_field) if isinstance(f, Q16Array) and f.mask_field is not None else 0
    enum = "NULL"
    if isinstance(f, EnumU8):
        enum = f"gs_can_enum_{f.cls.__name__.lower()}"
    bits = cf.signals[0].bits if cf.signals else 0
    return (f"    {{{kind}, {' | '.join(flags) or '0'}, {size}u, {bits}u, {len(cf.signals)}u, {mask_index}u, "
            f"offsetof(gs_msg_t, {_member(t, cf.name)}), {count}, {enum}}}, /* {cf.name} */")


def _enum_bitmap(cls: type) -> str:
    bits = [0] * 32
    for e in cls:  # type: ignore[attr-defined]
        v = int(e.value)
        bits[v >> 3] |= 1 << (v & 7)
    return ", ".join(f"0x{b:02x}u" for b in bits)


def can_layouts_h(servo_count: int) -> str:
    """The C text of ``gs_can_layouts.h`` for a robot of ``servo_count`` servos (1..32;
    :class:`protocol.codec.WireBoundError` outside)."""
    table = can_layouts(servo_count)
    mask_bytes = table.schema.mask_bytes
    out = [
        f"/* GENERATED by protocol.can.cgen from protocol.can.layouts.can_layouts({servo_count}) (the one message",
        " * declaration, protocol/codec.py LAYOUTS + CAN_FIXED): do not edit. Included once, by gs_can.c. */",
        "#ifndef GS_CAN_LAYOUTS_H",
        "#define GS_CAN_LAYOUTS_H",
        "",
        "#include <stddef.h>",
        "",
        '#include "gs_can.h"',
        '#include "gs_proto.h"',
        "",
        f"#define GS_CAN_SERVOS {servo_count}u",
    ]
    enums: dict[str, type] = {}
    for carried in table.fields.values():
        for cf in carried:
            if isinstance(cf.field, EnumU8):
                enums[cf.field.cls.__name__.lower()] = cf.field.cls
    for name, cls in sorted(enums.items()):
        out.append(f"static const uint8_t gs_can_enum_{name}[32] = {{{_enum_bitmap(cls)}}};")
    out.append("")
    max_signals = 0
    msg_rows = []
    for t, carried in table.fields.items():
        rows = [_field_row(t, cf, carried, mask_bytes) for cf in carried]
        lname = t.name.lower()
        if rows:
            out.append(f"static const gs_can_field_t gs_can_fields_{lname}[] = {{")
            out += rows
            out.append("};")
            msg_rows.append(f"    {{GS_MSG_TYPE_{t.name}, {len(rows)}u, gs_can_fields_{lname}}},")
        else:
            msg_rows.append(f"    {{GS_MSG_TYPE_{t.name}, 0u, NULL}},")
    out.append(f"static const gs_can_message_t gs_can_messages[{len(msg_rows)}] = {{")
    out += msg_rows
    out.append("};")
    out.append(f"#define GS_CAN_MESSAGE_COUNT {len(msg_rows)}u")
    out.append("")
    layout_rows = []
    for (fn, fd), lay in sorted(table.fixed.items(), key=lambda kv: (int(kv[0][0]), kv[0][1])):
        tag = f"{fn.name.lower()}_{'fd' if fd else 'classic'}"
        max_signals = max(max_signals, len(lay.signals))
        if lay.signals:
            out.append(f"static const gs_can_place_t gs_can_sig_{tag}[] = {{")
            out += [f"    {{{p.part}u, {p.start}u, {p.spec.bits}u, {1 if p.spec.signed else 0}u}}, /* {p.spec.name} */"
                    for p in lay.signals]
            out.append("};")
        out.append(f"static const uint8_t gs_can_part_bytes_{tag}[] = {{{', '.join(f'{b}u' for b in lay.part_bytes)}}};")
        crc = 1 if lay.has_crc else 0
        if crc:
            assert lay.signals[-1].spec.name == CRC_SIGNAL
        layout_rows.append(
            f"    {{GS_MSG_TYPE_{lay.msg_type.name}, 0x{int(fn):x}u /* {fn.name} */, {1 if fd else 0}u, {lay.parts}u, "
            f"{lay.length}u, {len(lay.signals)}u, {crc}u, gs_can_part_bytes_{tag}, "
            f"{'gs_can_sig_' + tag if lay.signals else 'NULL'}}},")
    out.append(f"static const gs_can_layout_t gs_can_layouts[{len(layout_rows)}] = {{")
    out += layout_rows
    out.append("};")
    out.append(f"#define GS_CAN_LAYOUT_COUNT {len(layout_rows)}u")
    out.append(f"#define GS_CAN_MAX_SIGNALS {max(max_signals, 1)}u")
    out.append(f"#define GS_CAN_HAS_BULK_TELEMETRY_CLASSIC "
               f"{0 if table.layout(FunctionCode.TELEMETRY, False) is not None else 1}u")
    out.append("")
    out.append("#endif")
    return "\n".join(out) + "\n"
