"""Jitter buffer order: frames sorted by (apply-at, arrival), a later frame at the same apply-at after an
earlier one, whether they arrive in time order (the appended fast path) or not (insorted)."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_sim.jitter_buffer import JitterBuffer


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 12), st.integers(0, 2)), max_size=40), st.integers(0, 14))
def test_frames_are_kept_in_apply_at_then_arrival_order(pushes: list[tuple[int, int]], pop_at: int) -> None:
    jb = JitterBuffer(capacity=32, n_servos=3)
    accepted = []
    for k, (slot, servo) in enumerate(pushes):
        t = slot * 10_000
        ok = jb.push(t, k, {servo: float(k)})
        assert ok == (len(accepted) < 32)
        if ok:
            accepted.append((t, k, servo))
    want = sorted(accepted, key=lambda a: (a[0], a[1]))  # stable: arrival order within an apply-at
    assert [(f.apply_at_us, f.seq) for f in jb._frames] == [(t, k) for t, k, _ in want]
    for servo in range(3):  # the next keyframe of each servo: its earliest, first-arrived frame
        mine = [(t, float(k)) for t, k, s in want if s == servo]
        assert jb.next_for(servo) == (mine[0] if mine else None)
    due = jb.pop_due(pop_at * 10_000)
    assert [f.seq for f in due] == [k for t, k, _ in want if t <= pop_at * 10_000]
    assert jb.first_apply_at == next((t for t, _, _ in want if t > pop_at * 10_000), None)
