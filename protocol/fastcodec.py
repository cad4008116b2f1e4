"""Fast payload codecs for the lockstep stream's messages: SERVO_FRAME (host -> board), TELEMETRY and
SIM_STATE (board -> host), each in one ``struct`` call instead of a field-by-field walk.

Why: a lockstep board and its host spend most of their non-physics time on these three messages, 50 of
each per simulated second; the generic codec (:mod:`protocol.codec`, one :class:`protocol.wiretypes.Field`
call per field, a context dict) took ~17 us to encode a 12-servo TELEMETRY and ~10 us to decode one.

Exactness: the same bytes and the same decoded values as :meth:`protocol.codec.WireSchema.encode_payload` /
:meth:`~protocol.codec.WireSchema.decode_payload`, by construction: a fast path takes only the common case
(plain ``int`` fields inside their ranges, finite float arrays whose codes the generic codec rounds with
``round`` too, float32 values inside float32's range; on decode, the expected length and counts and no NaN
code) and returns None for anything else, and the caller then runs the generic codec, which clamps,
quantises, or raises its :class:`protocol.codec.PayloadError` as always. A fast codec is built for a
schema only when the schema's layouts of the three messages are the ones written here (compared by their
wire descriptions, the text the schema hash is computed from): a changed message declaration turns the
fast path off rather than making it wrong. ``tests/protocol/test_fastcodec.py`` compares both paths on
random and edge-case messages, both schemas.

Pure: no I/O. :func:`fast_for` is what :mod:`protocol.framing` calls.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Any

from protocol.codec import WireSchema
from protocol.messages import FaultFlags, Message, MsgType, ServoFrame, SimState, Telemetry

__all__ = ["FAST_ERRORS", "FastCodec", "fast_for"]

_Q16_MAX = 32767
_Q16_NAN = -32768
_F32_MAX = 3.4028234663852886e38
_U64_MAX = (1 << 64) - 1
_U32_MAX = (1 << 32) - 1

_SIM = struct.Struct("<Q3f4fBB")
_SIM_SIZE = _SIM.size  # 38


def _wires(schema: WireSchema, t: MsgType) -> list[tuple[str, str]]:
    return [(name, f.wire) for name, f in schema.layouts[t]]


def _expected_wires(max_servos: int) -> dict[MsgType, list[tuple[str, str]]]:
    """The layouts this module's packers implement (name, wire description), for ``max_servos``."""
    mask = f"mask{16 if max_servos <= 16 else 32}[max={max_servos}]"
    return {
        MsgType.TELEMETRY: [
            ("board_time_us", "u64"), ("positions", "q16[count8]/10000"), ("velocities", "q16[count8]/1000"),
            ("efforts", "q16[count8]/1000"), ("imu_rpy", "q16[fixed3]/10000"),
            ("faults", "flags16[" + "FaultFlags:" + ",".join(f"{e.name}={int(e.value)}" for e in FaultFlags) + "]"),
            ("buffer_fill", "u16"), ("last_applied_seq", "u16w"), ("late_count", "u32"), ("dropped_count", "u32"),
            ("link_errors", "u32")],
        MsgType.SIM_STATE: [("board_time_us", "u64"), ("base_pos", "f32[3]"), ("base_quat", "f32[4]"),
                            ("objects", "u8"), ("toppled", "u8")],
        MsgType.SERVO_FRAME: [("apply_at_us", "u32w"), ("mask", mask),
                              ("targets", "q16[popcount(mask)]/10000,nonan")],
    }


def _codes(vals: Any, cpu: int) -> list[int] | None:
    """The q16 codes of ``vals`` as :meth:`protocol.wiretypes.Q16Array.encode` computes them in its common
    case (every scaled value strictly inside the code range, none NaN); None for any other case."""
    try:
        scaled = [f * cpu for f in map(float, vals)]
        if not (scaled and -_Q16_MAX < min(scaled) and max(scaled) < _Q16_MAX):
            return None
        return list(map(round, scaled))
    except (TypeError, ValueError):
        return None


class FastCodec:
    """The three packers and unpackers for one :class:`WireSchema` (see the module docstring); every
    method returns None where the generic codec must decide."""

    def __init__(self, schema: WireSchema) -> None:
        self.max_servos = schema.max_servos
        self.mask_char = "H" if schema.max_servos <= 16 else "I"
        self.mask_bytes = 2 if schema.max_servos <= 16 else 4
        self._tel: dict[int, struct.Struct] = {}
        self._frame: dict[int, struct.Struct] = {}
        self.encoders: dict[type, Callable[[Any], bytes | None]] = {
            Telemetry: self.encode_telemetry, SimState: self.encode_sim_state, ServoFrame: self.encode_servo_frame}
        self.decoders: dict[MsgType, Callable[[bytes], Message | None]] = {
            MsgType.TELEMETRY: self.decode_telemetry, MsgType.SIM_STATE: self.decode_sim_state,
            MsgType.SERVO_FRAME: self.decode_servo_frame}

    # --- TELEMETRY: u64, 3 x (u8 count + count x i16), 3 x i16, u16 x 3, u32 x 3 ---------------------

    def _tel_struct(self, n: int) -> struct.Struct:
        st = self._tel.get(n)
        if st is None:
            st = self._tel[n] = struct.Struct(f"<QB{n}hB{n}hB{n}h3hHHHIII")
        return st

    def encode_telemetry(self, m: Telemetry) -> bytes | None:
        n = len(m.positions)
        if not 0 < n <= self.max_servos or len(m.velocities) != n or len(m.efforts) != n or len(m.imu_rpy) != 3:
            return None
        t, fill, seq = m.board_time_us, m.buffer_fill, m.last_applied_seq
        late, dropped, errs = m.late_count, m.dropped_count, m.link_errors
        if not (t.__class__ is int and 0 <= t <= _U64_MAX and fill.__class__ is int and 0 <= fill <= 0xFFFF
                and seq.__class__ is int and late.__class__ is int and 0 <= late <= _U32_MAX
                and dropped.__class__ is int and 0 <= dropped <= _U32_MAX and errs.__class__ is int
                and 0 <= errs <= _U32_MAX):
            return None
        if m.faults.__class__ is not FaultFlags and m.faults.__class__ is not int:
            return None
        faults = int(m.faults)
        if not 0 <= faults <= 0xFFFF:
            return None
        p = _codes(m.positions, 10_000)
        v = _codes(m.velocities, 1_000)
        e = _codes(m.efforts, 1_000)
        imu = _codes(m.imu_rpy, 10_000)
        if p is None or v is None or e is None or imu is None:
            return None
        return self._tel_struct(n).pack(t, n, *p, n, *v, n, *e, *imu, faults, fill, seq & 0xFFFF, late, dropped, errs)

    def decode_telemetry(self, payload: bytes) -> Telemetry | None:
        if len(payload) < 9:
            return None
        n = payload[8]
        if not 0 < n <= self.max_servos or len(payload) != 35 + 6 * n:
            return None
        vals = self._tel_struct(n).unpack(payload)
        if vals[1 + n + 1] != n or vals[2 + 2 * n + 1] != n:
            return None
        codes = vals[2:2 + n] + vals[3 + n:3 + 2 * n] + vals[4 + 2 * n:4 + 3 * n] + vals[4 + 3 * n:7 + 3 * n]
        if _Q16_NAN in codes:
            return None
        i = 7 + 3 * n
        return Telemetry(
            board_time_us=vals[0],
            positions=tuple(map((10_000).__rtruediv__, vals[2:2 + n])),
            velocities=tuple(map((1_000).__rtruediv__, vals[3 + n:3 + 2 * n])),
            efforts=tuple(map((1_000).__rtruediv__, vals[4 + 2 * n:4 + 3 * n])),
            imu_rpy=tuple(map((10_000).__rtruediv__, vals[4 + 3 * n:i])),  # type: ignore[arg-type]
            faults=FaultFlags(vals[i]), buffer_fill=vals[i + 1], last_applied_seq=vals[i + 2],
            late_count=vals[i + 3], dropped_count=vals[i + 4], link_errors=vals[i + 5])

    # --- SIM_STATE: u64, f32 x 3, f32 x 4, u8, u8 ----------------------------------------------------

    @staticmethod
    def encode_sim_state(m: SimState) -> bytes | None:
        t, objects, toppled = m.board_time_us, m.objects, m.toppled
        if not (t.__class__ is int and 0 <= t <= _U64_MAX and objects.__class__ is int and 0 <= objects <= 255
                and toppled.__class__ is int and 0 <= toppled <= 255 and len(m.base_pos) == 3 and len(m.base_quat) == 4):
            return None
        try:
            floats = list(map(float, m.base_pos)) + list(map(float, m.base_quat))
        except (TypeError, ValueError):
            return None
        if not (-_F32_MAX <= min(floats) and max(floats) <= _F32_MAX):  # a NaN fails this too
            return None
        return _SIM.pack(t, *floats, objects, toppled)

    @staticmethod
    def decode_sim_state(payload: bytes) -> SimState | None:
        if len(payload) != _SIM_SIZE:
            return None
        v = _SIM.unpack(payload)
        return SimState(board_time_us=v[0], base_pos=v[1:4], base_quat=v[4:8],  # type: ignore[arg-type]
                        objects=v[8], toppled=v[9])

    # --- SERVO_FRAME: u32 apply-at (wraps), mask, popcount(mask) x i16 (no NaN) -----------------------

    def _frame_struct(self, n: int) -> struct.Struct:
        st = self._frame.get(n)
        if st is None:
            st = self._frame[n] = struct.Struct(f"<I{self.mask_char}{n}h")
        return st

    def encode_servo_frame(self, m: ServoFrame) -> bytes | None:
        at, mask = m.apply_at_us, m.mask
        if at.__class__ is not int or mask.__class__ is not int or mask <= 0 or mask >> self.max_servos:
            return None
        n = mask.bit_count()
        if len(m.targets) != n:
            return None
        codes = _codes(m.targets, 10_000)
        if codes is None:
            return None
        return self._frame_struct(n).pack(at & _U32_MAX, mask, *codes)

    def decode_servo_frame(self, payload: bytes) -> ServoFrame | None:
        mb = self.mask_bytes
        if len(payload) < 4 + mb:
            return None
        mask = int.from_bytes(payload[4:4 + mb], "little")
        n = mask.bit_count()
        if mask >> self.max_servos or len(payload) != 4 + mb + 2 * n or n == 0:
            return None
        v = self._frame_struct(n).unpack(payload)
        codes = v[2:]
        if _Q16_NAN in codes:
            return None
        return ServoFrame(apply_at_us=v[0], mask=mask, targets=tuple(map((10_000).__rtruediv__, codes)))


_FAST: dict[int, tuple[WireSchema, FastCodec | None]] = {}  # id -> (the schema, kept alive: ids stay unique)


def fast_for(schema: WireSchema) -> FastCodec | None:
    """The fast codec of ``schema``, or None when its layouts of the three messages are not the ones this
    module implements (see the module docstring). Cached per schema object."""
    hit = _FAST.get(id(schema))
    if hit is not None and hit[0] is schema:
        return hit[1]
    ok = all(_wires(schema, t) == w for t, w in _expected_wires(schema.max_servos).items())
    fc = FastCodec(schema) if ok else None
    if len(_FAST) > 64:  # schemas are few (one per servo-mask width); a tool building many keeps this bounded
        _FAST.clear()
    _FAST[id(schema)] = (schema, fc)
    return fc


#: what a fast packer may raise on a value the generic codec judges (a generator has no len, a str no float)
FAST_ERRORS = (TypeError, ValueError, OverflowError, AttributeError, struct.error)
