"""The lockstep board core against a model (hypothesis ``RuleBasedStateMachine``).

The model is a few lines of plain Python per rule: a jitter buffer as a list sorted by (apply-at,
arrival), the accept/refuse order of ``Board._servo_frame`` (ESTOPPED, FAULT_LATCHED, LATE,
TOO_FAR_FUTURE, BUFFER_FULL), FLUSH, ESTOP / ESTOP_CLEAR, and the watchdog (HOLD after
``watchdog`` of silence, latched CROUCH ``crouch_after`` later; entering either empties the buffer).
After every step the board's buffer, mode, last applied sequence and counters must equal the model's.
Messages travel through the real wire codec (``encode_frame`` -> ``FrameDecoder``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, invariant, precondition, rule

from firmware_sim.board import Board
from firmware_sim.config import BoardConfig
from firmware_sim.safety import Mode
from protocol.codec import quantize_position
from protocol.framing import Frame, FrameDecoder, encode_frame
from protocol.messages import Ack, Advance, Estop, EstopClear, Flush, Heartbeat, Message, Nack, NackReason, ServoFrame

TICK = 2000  # us at 500 Hz
CFG = dict(lockstep=True, buffer_depth=6, watchdog_ms=20, crouch_after_ms=30, max_late_us=6000, max_future_us=60_000)


@dataclass
class ModelFrame:
    apply_at: int
    order: int
    seq: int
    values: dict[int, float] = field(default_factory=dict)


class BoardModel(RuleBasedStateMachine):
    def __init__(self) -> None:
        super().__init__()
        self.board = Board(BoardConfig(**CFG))
        self.dec = FrameDecoder()
        self.seq = 0
        # model state
        self.now = 0
        self.buf: list[ModelFrame] = []
        self.order = 0
        self.estopped = False
        self.latched = False
        self.armed = False
        self.last_feed = 0
        self.hold_since: int | None = None
        self.last_applied = 0
        self.late = 0
        self.dropped = 0

    # --- plumbing -------------------------------------------------------------------------
    def send(self, msg: Message) -> list[Message]:
        self.seq = (self.seq + 1) & 0xFFFF
        replies: list[Message] = []
        for item in self.dec.feed(encode_frame(msg, self.seq)):
            assert isinstance(item, Frame)
            replies += self.board.handle(item.msg, item.seq)
        return replies

    def model_mode(self) -> Mode:
        if self.estopped:
            return Mode.ESTOP
        if self.latched:
            return Mode.CROUCH
        return Mode.HOLD if self.hold_since is not None else Mode.RUN

    def model_feed(self, t: int) -> None:
        self.armed = True
        self.last_feed = max(self.last_feed, t)
        if self.hold_since is not None and not self.latched:
            self.hold_since = None

    # --- rules ----------------------------------------------------------------------------
    @rule(
        dt=st.integers(-6, 40).map(lambda k: k * 1000),
        servos=st.sets(st.integers(0, 11), min_size=1, max_size=4),
        value=st.floats(-0.5, 0.5),
    )
    def servo_frame(self, dt: int, servos: set[int], value: float) -> None:
        t = max(0, self.now + dt)
        idx = sorted(servos)
        replies = self.send(ServoFrame(t, sum(1 << i for i in idx), tuple(value for _ in idx)))
        self.model_feed(self.now)
        expected: NackReason | None
        if self.estopped:
            expected = NackReason.ESTOPPED
        elif self.latched:
            expected = NackReason.FAULT_LATCHED
        elif t < self.now - CFG["max_late_us"]:
            expected = NackReason.LATE
        elif t > self.now + CFG["max_future_us"]:
            expected = NackReason.TOO_FAR_FUTURE
        elif len(self.buf) >= CFG["buffer_depth"]:
            expected = NackReason.BUFFER_FULL
        else:
            expected = None
        if expected is None:
            assert replies == [], f"frame due {t} at {self.now} refused: {replies}"
            self.order += 1
            self.buf.append(ModelFrame(t, self.order, self.seq, {i: quantize_position(value) for i in idx}))
            self.buf.sort(key=lambda f: (f.apply_at, f.order))
        else:
            assert len(replies) == 1 and isinstance(replies[0], Nack) and replies[0].reason is expected, (
                f"expected NACK {expected.name}, got {replies}"
            )
            if expected is NackReason.LATE:
                self.late += 1
            else:
                self.dropped += 1

    @rule(dt=st.integers(-4, 30).map(lambda k: k * 1000), servos=st.sets(st.integers(0, 11), min_size=1))
    def flush(self, dt: int, servos: set[int]) -> None:
        t = max(0, self.now + dt)
        replies = self.send(Flush(t, sum(1 << i for i in servos)))
        assert isinstance(replies[0], Ack)
        self.model_feed(self.now)
        for f in self.buf:
            if f.apply_at >= t:
                f.values = {i: v for i, v in f.values.items() if i not in servos}
        self.buf = [f for f in self.buf if f.values]

    @rule()
    def estop(self) -> None:
        assert isinstance(self.send(Estop())[0], Ack)
        self.model_feed(self.now)
        self.estopped = True
        self.buf.clear()

    @rule()
    def estop_clear(self) -> None:
        assert isinstance(self.send(EstopClear())[0], Ack)
        self.model_feed(self.now)
        self.estopped = self.latched = False
        self.hold_since = None
        self.last_feed = self.now

    @rule()
    def heartbeat(self) -> None:
        assert self.send(Heartbeat(0)) == []
        self.model_feed(self.now)

    @rule(n=st.integers(1, 40))
    def ticks(self, n: int) -> None:
        assert isinstance(self.send(Advance(self.now + n * TICK))[0], Ack)
        self.model_feed(self.now)
        for _ in range(n):
            assert self.board.can_tick()
            estopped_before = self.estopped
            self.model_tick()
            self.board.tick()
            assert self.board.mode is self.model_mode(), f"tick at {self.now - TICK}: board {self.board.mode}"
            if estopped_before:  # ESTOP takes effect at the first tick after it arrived, and holds
                assert np.array_equal(self.board.desired, self.board.hold_q)

    def model_tick(self) -> None:
        t = self.now
        before = self.model_mode()
        if self.armed and not self.estopped and not self.latched:
            if self.hold_since is None and t - self.last_feed > CFG["watchdog_ms"] * 1000:
                self.hold_since = t
            if self.hold_since is not None and t - self.hold_since >= CFG["crouch_after_ms"] * 1000:
                self.latched = True
        mode = self.model_mode()
        if mode is not before and mode in (Mode.HOLD, Mode.CROUCH):
            self.buf.clear()
        if mode is Mode.RUN:
            while self.buf and self.buf[0].apply_at <= t:
                f = self.buf.pop(0)
                self.last_applied = f.seq
                self.model_feed(f.apply_at)
        self.now += TICK

    # --- invariants -----------------------------------------------------------------------
    @invariant()
    def matches_model(self) -> None:
        b = self.board
        assert b.now_us == self.now
        got = [(f.apply_at_us, f.seq, f.values) for f in b.buffer._frames]
        want = [(f.apply_at, f.seq, f.values) for f in self.buf]
        assert got == want, f"jitter buffer {got} != model {want}"
        assert b.mode is self.model_mode(), f"board {b.mode}, model {self.model_mode()}"
        assert b.last_applied_seq == self.last_applied
        assert (b.late_count, b.dropped_count) == (self.late, self.dropped)

    @precondition(lambda self: self.estopped)
    @invariant()
    def estop_wins(self) -> None:
        assert len(self.board.buffer) == 0 and self.board.mode is Mode.ESTOP


BoardModel.TestCase.settings = settings(
    max_examples=60, stateful_step_count=40, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
TestBoardModel = BoardModel.TestCase
