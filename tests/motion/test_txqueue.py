"""The streamer's transmit queue (host.motion.txqueue): earliest apply time first, and a FLUSH acts on
held frames as the board's would, so the board's jitter buffer ends up as if nothing had been held.

The equivalence is checked against the board's own jitter buffer (firmware_sim.jitter_buffer, the
Python reference of the C firmware's): one board gets every message in the order it was produced
(a FIFO line), the other gets FLUSHes and direct frames at once and held frames whenever the
pacing writes them.
"""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_sim.jitter_buffer import JitterBuffer
from host.motion.txqueue import EdfFrameQueue
from protocol.messages import ServoFrame

N = 6


def frame(t: int, mask: int, base: float = 0.0) -> ServoFrame:
    return ServoFrame(t, mask, tuple(base + i for i in range(N) if mask >> i & 1))


def test_frames_leave_earliest_apply_time_first_ties_in_queue_order() -> None:
    q = EdfFrameQueue()
    for t, base in ((30, 0.0), (10, 1.0), (20, 2.0), (10, 3.0)):
        assert q.push(frame(t, 0b11, base))
    out = [(f.apply_at_us, f.targets[0]) for f, _ in q.drain()]
    assert out == [(10, 1.0), (10, 3.0), (20, 2.0), (30, 0.0)]
    assert len(q) == 0 and q.pop() is None


def test_a_flush_removes_its_servos_from_held_frames_due_from_its_time() -> None:
    q = EdfFrameQueue()
    q.push(frame(10, 0b111111))
    q.push(frame(20, 0b111111))
    q.push(frame(20, 0b000110, 100.0))
    q.flush(20, 0b000110)
    out = [f for f, _ in q.drain()]
    assert out[0] == frame(10, 0b111111)  # due before the flush: untouched
    assert out[1] == ServoFrame(20, 0b111001, (0.0, 3.0, 4.0, 5.0))  # servos 1 and 2 gone, the rest in order
    assert len(out) == 2 and q.dropped == 1  # the frame with only servos 1 and 2 is dropped


def test_a_dropped_frames_callback_gets_the_next_written_number() -> None:
    q = EdfFrameQueue()
    got: dict[str, int] = {}
    q.push(frame(20, 0b1), lambda seq: got.setdefault("dropped", seq))
    q.push(frame(30, 0b10), lambda seq: got.setdefault("kept", seq))
    q.flush(0, 0b1)
    item = q.pop()
    assert item is not None
    f, callbacks = item
    for cb in callbacks:
        cb(7)
    assert f.apply_at_us == 30 and got == {"kept": 7, "dropped": 7}


def test_the_queue_is_bounded_and_refuses_rather_than_loses() -> None:
    q = EdfFrameQueue(capacity=3)
    assert all(q.push(frame(t, 1)) for t in (1, 2, 3))
    assert not q.push(frame(4, 1))
    assert len(q) == 3
    q.flush(0, 1)  # emptied frames still take room until they leave the heap
    assert len(q) == 0
    assert all(q.push(frame(t, 1)) for t in (5, 6, 7))
    assert not q.push(frame(8, 1))  # 3 emptied + 3 held = 2 x capacity
    assert [f.apply_at_us for f, _ in q.drain()] == [5, 6, 7]


def _effective(buf: JitterBuffer) -> dict[tuple[int, int], float]:
    """What the board would apply: per (apply time, servo) the value of the last frame to set it."""
    out: dict[tuple[int, int], float] = {}
    for f in buf.pop_due(1 << 60):
        for i, v in f.values.items():
            out[(f.apply_at_us, i)] = v
    return out


def _push(buf: JitterBuffer, f: ServoFrame) -> None:
    bits = [i for i in range(N) if f.mask >> i & 1]
    assert buf.push(f.apply_at_us, 0, dict(zip(bits, f.targets, strict=True)))


op = st.one_of(
    st.tuples(st.just("queue"), st.integers(0, 12), st.integers(1, (1 << N) - 1)),
    st.tuples(st.just("start"), st.integers(0, 12), st.integers(1, (1 << N) - 1)),  # a direct frame, then FLUSH
    st.tuples(st.just("flush"), st.integers(0, 12), st.integers(1, (1 << N) - 1)),
    st.tuples(st.just("write"), st.integers(1, 3), st.just(0)),  # the pacing writes up to k held frames
)


@settings(max_examples=300, deadline=None)
@given(st.lists(op, max_size=40))
def test_the_board_ends_up_as_if_every_message_had_been_written_in_order(ops: list[tuple[str, int, int]]) -> None:
    fifo, paced = JitterBuffer(1024, N), JitterBuffer(1024, N)
    q = EdfFrameQueue(capacity=4)  # small: a full queue writes its head first (BoardFrameLink.queue_frame)
    for k, (kind, slot, mask) in enumerate(ops):
        t = slot * 10
        f = frame(t, mask, base=k * 10.0)
        if kind == "queue":
            _push(fifo, f)
            while not q.push(f):
                head = q.pop()
                if head is not None:
                    _push(paced, head[0])
        elif kind == "start":  # start_now: the first frame at t, then a FLUSH from t + 1, both at once;
            q.flush(t, mask)  # the held frames lose its servos from t on before it is written
            for board in (fifo, paced):
                _push(board, f)
                board.flush(t + 1, mask)
        elif kind == "flush":
            fifo.flush(t, mask)
            q.flush(t, mask)
            paced.flush(t, mask)
        else:
            for _ in range(slot):
                item = q.pop()
                if item is not None:
                    _push(paced, item[0])
    for held, _ in q.drain():
        _push(paced, held)
    assert _effective(paced) == _effective(fifo)
