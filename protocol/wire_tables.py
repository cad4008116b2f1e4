"""Render the wire-protocol reference (``docs/wire-protocol.md``) from the one message declaration.

Pure: :func:`render` returns Markdown built from :data:`protocol.codec.LAYOUTS` (payload tables:
offsets, widths, scales), :mod:`protocol.framing` (frame layout, COBS, CRC parameters),
:func:`protocol.codec.schema_text` (how the schema hash is computed, its current value),
:data:`protocol.codec.CAN_FIXED` with the layouts derived from it
(:data:`protocol.can.layouts.FIXED_LAYOUTS`) and :mod:`protocol.can.ids` (the CAN form), and the
board behaviour a client must know, whose numbers the caller passes (:class:`BoardFacts`, from the
board's defaults: ``python -m firmware_sim.wire_reference [--check]`` writes the file).

The tables have a fixed shape so a program can read them (tests/cfirmware/test_reference_host.py
writes a host from them alone): ``| offset | field | type | bytes | scale | notes |`` per payload,
where ``type`` is one of ``u8 u16 u32 u64 i8 i16 i32 i64`` (little-endian), ``bool`` (u8 0/1),
``enum8 NAME``, ``flags16 NAME``, ``mask16``, ``i16[N]``, ``i16[popcount(FIELD)]``,
``u8 n + i16[n]``, ``f32[N]``, ``u8 len + utf8[len<=MAX]``, ``bytes[rest<=MAX]``; an offset is
``var`` after the first variable-length field.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntFlag

from protocol import codec as c
from protocol import framing
from protocol import messages as m
from protocol.can import ids as can_ids
from protocol.can.layouts import DEFAULT_SERVO_COUNT as CAN_SERVOS
from protocol.can.layouts import FIXED_LAYOUTS, HEADER_BITS, PART_BITS, SEQ_BITS, can_layouts
from protocol.messages import MsgType
from protocol.wiretypes import DECLARED

__all__ = ["BoardFacts", "DIRECTION", "field_type", "render"]

#: who sends each message type, as declared (:class:`protocol.wiretypes.Sender`)
DIRECTION = {t: DECLARED[int(t)].sender.value for t in MsgType}


@dataclass(frozen=True)
class BoardFacts:
    """Board behaviour numbers the reference states (the emulated board's defaults)."""

    rate_hz: int
    telemetry_rate_hz: int
    watchdog_ms: int
    crouch_after_ms: int
    max_late_us: int
    max_future_us: int
    buffer_depth: int
    c_buffer_depth: int
    reply_policy: str  # the board's docstring paragraph on replies


def _unit(t: MsgType, name: str, f: c.Field) -> str:
    """The scale column: counts per unit for q16 arrays, else the declared unit (``us`` shown as µs)."""
    unit = c.field_unit(name, f)
    if isinstance(f, c.Q16Array):
        return f"1/{f.cpu} {unit}"
    if isinstance(f, c.F32Array):
        return unit
    return {"us": "1 µs", "ms": "1 ms", "Hz": "1 Hz"}.get(unit, unit)


def field_type(f: c.Field) -> tuple[str, str]:
    """(type, bytes) of one wire field in the reference's vocabulary."""
    if isinstance(f, c.UInt):
        return f"u{8 * f.size}", str(f.size)
    if isinstance(f, c.SInt):
        return f"i{8 * f.size}", str(f.size)
    if isinstance(f, c.Bool):
        return "bool", "1"
    if isinstance(f, c.EnumU8):
        return f"enum8 {f.cls.__name__}", "1"
    if isinstance(f, c.Flags16):
        return f"flags16 {f.cls.__name__}", "2"
    if isinstance(f, c.Mask):
        return f"mask{8 * f.size}", str(f.size)
    if isinstance(f, c.Q16Array):
        if f.fixed is not None:
            return f"i16[{f.fixed}]", str(2 * f.fixed)
        if f.mask_field is not None:
            return f"i16[popcount({f.mask_field})]", "2 each"
        return "u8 n + i16[n]", "1 + 2n"
    if isinstance(f, c.F32Array):
        return f"f32[{f.n}]", str(4 * f.n)
    if isinstance(f, c.Str8):
        return f"u8 len + utf8[len<={f.max_bytes}]", "1 + len"
    if isinstance(f, c.RestBytes):
        return f"bytes[rest<={f.max_bytes}]", "rest"
    raise NotImplementedError(f"no reference type for wire field {type(f).__name__} ({f.wire})")


def _notes(t: MsgType, name: str, f: c.Field) -> str:
    out = []
    if isinstance(f, c.UInt) and f.wrap:
        out.append(f"wraps modulo 2**{8 * f.size}")
    if name == "apply_at_us":
        out.append("board clock; the board unwraps it to the full time nearest its own clock")
    if isinstance(f, c.Mask):
        out.append(f"bit i = servo id i+1; bits >= {f.max_servos} are refused")
    if isinstance(f, c.Q16Array):
        out.append("-32768 is refused" if not f.allow_nan else "-32768 = unknown (NaN)")
        out.append("clamped to ±32767 by the sender")
    if isinstance(f, c.Bool):
        out.append("0 or 1, anything else is refused")
    if isinstance(f, c.EnumU8):
        out.append("unknown values are refused")
    if isinstance(f, c.Str8):
        out.append("strict UTF-8, not terminated")
    if t is MsgType.CAMERA_CHUNK and name == "index":
        out.append("must be below total")
    return "; ".join(out)


def _payload_table(t: MsgType) -> list[str]:
    lines = ["| offset | field | type | bytes | scale | notes |", "| --- | --- | --- | --- | --- | --- |"]
    off: int | None = 0
    for name, f in c.LAYOUTS[t]:
        typ, size = field_type(f)
        lines.append(f"| {off if off is not None else 'var'} | {name} | {typ} | {size} | {_unit(t, name, f)} | "
                     f"{_notes(t, name, f)} |")
        if off is not None and size.isdigit():
            off += int(size)
        else:
            off = None
    if not c.LAYOUTS[t]:
        lines.append("| - | (empty payload) | | 0 | | |")
    return lines


def _enum_table(cls: type) -> list[str]:
    kind = "bit" if issubclass(cls, IntFlag) else "value"
    lines = [f"| {kind} | name |", "| --- | --- |"]
    for e in cls:  # type: ignore[attr-defined]
        lines.append(f"| {int(e.value):#06x} | {e.name} |" if kind == "bit" else f"| {int(e.value)} | {e.name} |")
    return lines


def _can_form_table() -> list[str]:
    """Per fixed-layout message: each serial field and the CAN signals carrying it (from CAN_FIXED)."""
    lines = ["| message | field | serial | CAN signals | CAN notes |", "| --- | --- | --- | --- | --- |"]
    table = can_layouts(CAN_SERVOS)
    for t in sorted(c.CAN_FIXED, key=int):
        carried = table.fields[t]
        if not carried:
            lines.append(f"| {t.name} | (header only) | | | |")
        for cf in carried:
            serial, _ = field_type(cf.field)
            sigs = cf.signals
            if not sigs:
                lines.append(f"| {t.name} | {cf.name} | {serial} | (not carried) | "
                             "must be empty; otherwise the message goes as ISO-TP bulk |")
                continue
            s0 = sigs[0]
            kind = f"{'i' if s0.signed else 'u'}{s0.bits}"
            if isinstance(cf.field, c.Q16Array) and cf.field.fixed is None:
                names = f"`{sigs[0].name[:-2]}NN` ({kind} × N, one per servo)"
                note = ("-32768 where the mask bit is clear" if cf.field.mask_field
                        else "-32768 past the values sent")
            else:
                names = ", ".join(f"`{x.name}`" for x in sigs) + f" ({kind})"
                note = s0.comment if s0.comment != "int16; -32768 = unknown (NaN)" else ""
            lines.append(f"| {t.name} | {cf.name} | {serial} | {names} | {note} |")
    return lines


def _can_section() -> list[str]:
    out = ["## CAN form", "",
           f"11-bit COB-IDs (CiA 301 style): `cob_id = function_code << 7 | node_id`, node 1..{can_ids.MAX_NODE}; "
           f"`0x000` is the broadcast ESTOP. Every fixed-layout frame starts with a 16-bit little-endian header: bits "
           f"0..{PART_BITS - 1} the part index, bits {PART_BITS}..{HEADER_BITS - 1} the sequence number modulo "
           f"2**{SEQ_BITS}. Signals follow little-endian, never straddling a frame; a message ends with `crc16` "
           f"(CRC-16/X-25 over the data bytes of all its parts with that field zero). Layouts are for "
           f"{CAN_SERVOS} servos (`protocol.can.layouts.can_layouts(N)` places them for N servos). Messages without a fixed layout travel as ISO-TP units on BULK_TO_BOARD/BULK_TO_HOST: "
           "`type u8 | seq u16 LE | the serial payload | crc16 LE`.", "",
           "| function code | name | direction |", "| --- | --- | --- |"]
    for fn in can_ids.FunctionCode:
        d = "host → board" if fn in can_ids.HOST_TO_BOARD else "board → host"
        out.append(f"| {int(fn):#x} | {fn.name} | {d} |")
    out += ["", "### Serial fields on CAN", "",
            "The real-time messages below have a fixed CAN layout (`protocol/codec.py` `CAN_FIXED`: the fields whose "
            "CAN form differs from the serial one); each serial field travels as these signals, in this order, "
            "followed by `crc16`. Per-servo arrays have one signal per servo of the robot (`NN` = 01 .. N); a "
            "servo mask is 16 bits for robots of up to 16 servos, 32 above.", ""]
    out += _can_form_table()
    out.append("")
    for fd in (False, True):
        out.append(f"### {'CAN FD' if fd else 'Classic CAN'} signal placement")
        out.append("")
        for (fn, is_fd), lay in sorted(FIXED_LAYOUTS.items(), key=lambda kv: (int(kv[0][0]), kv[0][1])):
            if is_fd != fd:
                continue
            out.append(f"#### {fn.name} ({lay.parts} part{'s' if lay.parts > 1 else ''}, {lay.length} bytes each)")
            out.append("")
            out.append("| part | start bit | bits | signed | signal | scale | unit |")
            out.append("| --- | --- | --- | --- | --- | --- | --- |")
            for p in lay.signals:
                s = p.spec
                out.append(f"| {p.part} | {p.start} | {s.bits} | {'yes' if s.signed else 'no'} | {s.name} | "
                           f"{s.scale:g} | {s.unit} |")
            out.append("")
    return out


def render(facts: BoardFacts) -> str:
    """The whole reference as Markdown."""
    crc = framing
    out = [
        "<!-- GENERATED by `python -m firmware_sim.wire_reference` from protocol/codec.py LAYOUTS and CAN_FIXED: do not edit. -->",
        "# GhostShell wire protocol reference",
        "",
        f"Protocol version {m.PROTOCOL_VERSION}. Everything below is generated from the message declaration "
        "(`protocol/codec.py` `LAYOUTS`, with `CAN_FIXED` for the CAN form) that also generates the Python codec, "
        "the C codec (`firmware_sim/c/schema16/gs_proto.[ch]` for robots of up to 16 servos, "
        "`firmware_sim/c/schema32/` above), the CAN layouts and DBCs, and this page. All integers are little-endian.",
        "",
        "## Serial framing",
        "",
        "| offset | field | type | bytes | notes |",
        "| --- | --- | --- | --- | --- |",
        f"| 0 | version | u8 | 1 | {m.PROTOCOL_VERSION} |",
        "| 1 | type | u8 | 1 | message type (table below) |",
        "| 2 | seq | u16 | 2 | one counter per direction, starts anywhere, wraps |",
        f"| 4 | length | u8 | 1 | payload bytes (0..{c.MAX_PAYLOAD}) |",
        f"| 5 | payload | | length | the message's layout |",
        "| 5+length | crc | u16 | 2 | CRC over bytes 0 .. 5+length-1 |",
        "",
        f"CRC: CRC-16/X-25 (poly `0x1021` reflected, init `0xFFFF`, xorout `0xFFFF`; `{crc.CRC_NAME}` in crcmod); "
        f"check value of `b\"123456789\"` is `{crc.CRC_CHECK:#06x}`.",
        "",
        "The whole block (header, payload, CRC) is COBS-encoded and followed by one `0x00` delimiter. "
        f"The longest valid frame is {crc.MAX_WIRE_FRAME} bytes on the wire. Receivers resynchronise at the next "
        f"`0x00`; a run of more than {crc.DEFAULT_MAX_FRAME_BYTES} bytes without one is discarded. A lone `0x00` "
        "is an idle delimiter (send one after opening a port to flush a partial frame at the receiver).",
        "",
        "## Schema hash",
        "",
        f"HELLO and CAPS carry `schema_hash`, a u32: the first four bytes (big-endian) of SHA-256 over the "
        f"schema text below (UTF-8). **Current value: `{c.SCHEMA_HASH:#010x}`** (robots of up to "
        f"{c.WIRE_SCHEMA_16.max_servos} servos, the tables below). Robots of "
        f"{c.WIRE_SCHEMA_16.max_servos + 1}..{c.WIRE_SCHEMA_32.max_servos} servos use the u32-mask schema, hash "
        f"`{c.WIRE_SCHEMA_32.hash:#010x}` (every `mask16` below is a `mask32`, the u8 counts go up to "
        f"{c.WIRE_SCHEMA_32.max_servos}). A board answers a HELLO with another hash with NACK SCHEMA_MISMATCH.",
        "",
        "<details><summary>schema text</summary>",
        "",
        "```text",
        c.schema_text().rstrip("\n"),
        "```",
        "",
        "</details>",
        "",
        "## Message types",
        "",
        "| type | name | direction | meaning |",
        "| --- | --- | --- | --- |",
    ]
    for t in sorted(MsgType, key=int):
        doc = (c.MESSAGE_CLASSES[t].__doc__ or "").strip().splitlines()
        out.append(f"| {int(t):#04x} | {t.name} | {DIRECTION[t]} | {doc[0] if doc else ''} |")
    out += ["", "## Payload layouts", ""]
    for t in sorted(MsgType, key=int):
        out.append(f"### {t.name} ({int(t):#04x})")
        out.append("")
        out += _payload_table(t)
        out.append("")
    out += ["## Enumerations", ""]
    for cls in (m.NackReason, m.FaultFlags, m.ConfigKey, m.SpeakerAction, m.SoundKind, m.ScreenTarget):
        out.append(f"### {cls.__name__}")
        out.append("")
        out += _enum_table(cls)
        out.append("")
    out += [
        "## Servos and masks",
        "",
        f"Servo `i` on the wire (0-based) is the servo with id `i + 1` in the robot's servo table "
        f"(`robots/<name>/servos.toml`; `ghostshell robots show NAME` prints it). A `mask` has bit `i` set for servo "
        f"id `i + 1`; per-servo arrays list only the masked servos, in ascending id order. This schema carries at most "
        f"{m.MAX_SERVOS} servos (a u16 mask). CAPS reports the robot's name, its servo count and `servo_table_hash` "
        "(first four bytes of SHA-256 over the table's canonical text); the host refuses a board whose values differ "
        "from the robot it was started for.",
        "",
        "## Board behaviour a client must know",
        "",
        f"- **HELLO is optional** for the board (it handles every message without one) but a host should send it: "
        f"CAPS tells the schema, robot, servo count, control rate ({facts.rate_hz} Hz), jitter-buffer depth (frames; "
        f"{facts.buffer_depth} on the Python board, {facts.c_buffer_depth} on the C firmware), telemetry rate, board "
        "time and whether the board runs in lockstep. A HELLO also restarts the board's count of lost sequence numbers.",
        f"- **Telemetry**: TELEMETRY (then SIM_STATE, emulator only) every `round({facts.rate_hz} / telemetry_rate)` "
        f"ticks ({facts.telemetry_rate_hz} Hz by default), stamped with the board time after that tick. "
        "`last_applied_seq` is the sequence number of the last SERVO_FRAME applied: it confirms frames (accepted frames "
        "get no ACK).",
        f"- **Lockstep start and ADVANCE**: a lockstep board starts at board time 0 and runs a tick at time `t` only "
        "while a received SERVO_FRAME is due at or after `t`, or `t < until_us` of an ADVANCE. Send ADVANCE (or frames) "
        "to make time pass; a board that cannot tick handles the next message. ADVANCE to a realtime board is NACKed "
        "NOT_LOCKSTEP.",
        f"- **SERVO_FRAME window**: a frame due more than {facts.max_late_us} µs before the board clock is NACKed LATE, "
        f"more than {facts.max_future_us} µs after it TOO_FAR_FUTURE, a full buffer BUFFER_FULL. The board interpolates "
        "linearly from each servo's last applied keyframe to its next buffered one and clamps to the servo table's "
        "range and speed. Frames with the same apply time: the later one wins for the servos both cover.",
        f"- **Watchdog**: armed by the first valid message. After {facts.watchdog_ms} ms without a valid message the "
        f"board HOLDs (telemetry WATCHDOG_HOLD; the next valid message resumes); {facts.crouch_after_ms} ms later it "
        "moves to the robot's safe pose and latches WATCHDOG_FAULT, refusing frames (NACK FAULT_LATCHED) until "
        "ESTOP_CLEAR. In lockstep, applied frames feed it too (board time). Send HEARTBEAT when idle. ESTOP holds where "
        "the servos are and refuses frames (ESTOPPED) until ESTOP_CLEAR.",
        "- **TIME_SYNC**: the host sends `t1_host_us` (its clock at send); the reply carries it back with "
        "`t2_board_us` (board clock at receive) and `t3_board_us` (board clock at send). With `t4` the host clock at "
        "receipt: offset = ((t2 - t1) + (t3 - t4)) / 2, round trip = (t4 - t1) - (t3 - t2) (NTP).",
        "- **Servo bus faults** (C firmware): a servo that stops answering latches SERVO_FAULT in telemetry, one NACK "
        "SERVO_FAULT (msg_type SERVO_FRAME) names it, every servo holds and frames are refused until ESTOP_CLEAR.",
        "- **Camera**: the C firmware has no renderer and NACKs CAMERA_CAPTURE with NO_RENDERER.",
        "",
        "Reply policy (the Python board's, `firmware_sim/board.py`):",
        "",
        "> " + " ".join(facts.reply_policy.split()),
        "",
    ]
    out += _can_section()
    return "\n".join(out).rstrip("\n") + "\n"
