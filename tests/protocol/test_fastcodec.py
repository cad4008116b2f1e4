"""protocol.fastcodec: the fast packers give the generic codec's bytes and values, or step aside."""

from __future__ import annotations

import math
import random
import struct

import pytest

from protocol.codec import WIRE_SCHEMA_16, WIRE_SCHEMA_32, PayloadError, WireSchema, msg_type_of
from protocol.fastcodec import FAST_ERRORS, fast_for
from protocol.framing import FrameDecoder, encode_frame, encode_raw_frame
from protocol.messages import FaultFlags, Message, MsgType, ServoFrame, SimState, Telemetry

SCHEMAS = (WIRE_SCHEMA_16, WIRE_SCHEMA_32)
EDGE = (0.0, -0.0, 3.2766, -3.2766, 3.27665, 3.2767, -3.2767, 3.3, -40.0, 1e300, math.inf, -math.inf, math.nan,
        0.00005, -0.00005, 0.00015, 32.7665, 32.767, -32.7675)


def _floats(rng: random.Random, n: int, span: float, edges: bool) -> tuple[float, ...]:
    return tuple(rng.choice(EDGE) if edges and rng.random() < 0.15 else rng.uniform(-span, span) for _ in range(n))


def _int(rng: random.Random, hi: int, edges: bool) -> int:
    return rng.choice((-1, 0, hi, hi + 1, 1 << 70)) if edges and rng.random() < 0.1 else rng.randint(0, hi)


def _telemetry(rng: random.Random, schema: WireSchema, edges: bool) -> Telemetry:
    n = rng.randint(1, schema.max_servos) if not (edges and rng.random() < 0.05) else rng.choice((0, schema.max_servos + 1))
    m = rng.choice((n, n, n, n + 1)) if edges else n
    return Telemetry(
        board_time_us=_int(rng, (1 << 64) - 1, edges), positions=_floats(rng, n, 3.5, edges),
        velocities=_floats(rng, m, 30.0 if not edges else 40.0, edges), efforts=_floats(rng, n, 30.0 if not edges else 40.0, edges),
        imu_rpy=_floats(rng, 3, 3.3, edges),  # type: ignore[arg-type]
        faults=FaultFlags(rng.randint(0, 127)) if not edges or rng.random() < 0.8 else rng.choice((0, 5, 1 << 16, -1)),  # type: ignore[arg-type]
        buffer_fill=_int(rng, 0xFFFF, edges), last_applied_seq=rng.randint(0, 1 << 17),
        late_count=_int(rng, (1 << 32) - 1, edges), dropped_count=_int(rng, (1 << 32) - 1, edges),
        link_errors=_int(rng, (1 << 32) - 1, edges))


def _sim_state(rng: random.Random, edges: bool) -> SimState:
    vals = _floats(rng, 7, 2.0, edges)
    if edges and rng.random() < 0.1:
        vals = vals[:6] + (rng.choice((1e39, -1e39, 3.4028234663852886e38)),)
    return SimState(_int(rng, (1 << 64) - 1, edges), vals[:3], vals[3:],  # type: ignore[arg-type]
                    objects=_int(rng, 255, edges), toppled=_int(rng, 255, edges))


def _servo_frame(rng: random.Random, schema: WireSchema, edges: bool) -> ServoFrame:
    mask = rng.randint(1, (1 << schema.max_servos) - 1)
    if edges and rng.random() < 0.05:
        mask = rng.choice((0, 1 << schema.max_servos, -1))
    n = max(0, mask).bit_count() + (rng.choice((0, 0, 0, 1)) if edges else 0)
    return ServoFrame(_int(rng, (1 << 33), edges), mask, _floats(rng, n, 3.3, edges))


def _same(a: Message, b: Message) -> bool:
    """Equal, NaN equal to NaN, and the same types field by field."""
    if type(a) is not type(b):
        return False
    for k, va in vars(a).items():
        vb = getattr(b, k)
        if type(va) is not type(vb):
            return False
        if isinstance(va, tuple):
            if len(va) != len(vb) or any(type(x) is not type(y) or not (x == y or (x != x and y != y))
                                         for x, y in zip(va, vb)):
                return False
        elif va != vb:
            return False
    return True


@pytest.mark.parametrize("schema", SCHEMAS, ids=lambda s: f"u{s.mask_bytes * 8}")
@pytest.mark.parametrize("edges", [False, True], ids=["common", "edges"])
def test_fast_encode_decode_equal_the_generic_codec(schema: WireSchema, edges: bool) -> None:
    fc = fast_for(schema)
    assert fc is not None
    rng = random.Random(46 + schema.max_servos + edges)
    fast_used = 0
    for _ in range(3000):
        msg: Message = rng.choice((_telemetry(rng, schema, edges), _sim_state(rng, edges), _servo_frame(rng, schema, edges)))
        try:
            generic: bytes | None = schema.encode_payload(msg)
        except PayloadError:
            generic = None
        enc = fc.encoders[type(msg)]
        try:
            fast = enc(msg)
        except FAST_ERRORS:
            fast = None
        if fast is not None:
            fast_used += 1
            assert fast == generic, msg  # the fast path never takes what the generic refuses, nor differs
        if generic is None:
            with pytest.raises(PayloadError):
                encode_frame(msg, 1, schema)
            continue
        raw = encode_frame(msg, 7, schema)
        assert raw == encode_raw_frame(int(msg_type_of(msg)), 7, generic)
        (frame,) = FrameDecoder(schema=schema).feed(raw)
        t = msg_type_of(msg)
        assert _same(frame.msg, schema.decode_payload(t, generic))  # type: ignore[union-attr]
    assert fast_used > (2000 if not edges else 300)  # the fast path is the common case


@pytest.mark.parametrize("schema", SCHEMAS, ids=lambda s: f"u{s.mask_bytes * 8}")
def test_fast_decode_of_any_payload_equals_the_generic_codec(schema: WireSchema) -> None:
    """Random and mutated payloads (wrong lengths, counts, NaN codes, mask bits): the fast decoder
    returns the generic codec's message or None, never a different one."""
    fc = fast_for(schema)
    assert fc is not None
    rng = random.Random(4646 + schema.max_servos)
    for _ in range(4000):
        t = rng.choice((MsgType.TELEMETRY, MsgType.SIM_STATE, MsgType.SERVO_FRAME))
        base = schema.encode_payload(_telemetry(rng, schema, False) if t is MsgType.TELEMETRY
                                     else _sim_state(rng, False) if t is MsgType.SIM_STATE
                                     else _servo_frame(rng, schema, False))
        p = bytearray(base)
        for _ in range(rng.randint(0, 3)):
            op = rng.random()
            if op < 0.3 and p:
                p[rng.randrange(len(p))] = rng.choice((0, 1, 0x80, 0xFF, rng.randrange(256)))
            elif op < 0.5 and p:
                del p[rng.randrange(len(p)):]
            elif op < 0.6:
                p += bytes([rng.randrange(256)])
            elif op < 0.8 and len(p) > 10:
                at = rng.randrange(8, len(p) - 1)
                p[at:at + 2] = struct.pack("<h", -32768)
        fast = fc.decoders[t](bytes(p))
        try:
            generic: Message | None = schema.decode_payload(t, bytes(p))
        except PayloadError:
            generic = None
        if fast is not None:
            assert generic is not None and _same(fast, generic), (t, bytes(p).hex())


def test_a_changed_layout_turns_the_fast_path_off() -> None:
    """A schema whose TELEMETRY layout is not the one fastcodec packs gets no fast codec."""
    layouts = dict(WIRE_SCHEMA_16.layouts)
    layouts[MsgType.TELEMETRY] = layouts[MsgType.TELEMETRY][:-1]
    odd = WireSchema(16, layouts, "odd", 0)
    assert fast_for(odd) is None
    assert fast_for(WIRE_SCHEMA_16) is not None
