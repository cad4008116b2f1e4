"""The mixer composes segments per servo, loops persistent motions and reports first/last frames."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from host.motion.mixer import Mixer


@dataclass(frozen=True)
class M:
    servos: tuple[int, ...]
    t: np.ndarray
    q: np.ndarray
    loop_from: float | None = None


def ramp(servos: tuple[int, ...], q0: float, q1: float, dur: float, loop_from: float | None = None) -> M:
    return M(servos, np.array([0.0, dur]), np.array([[q0] * len(servos), [q1] * len(servos)]), loop_from)


def test_idle_servos_hold_and_segment_interpolates() -> None:
    mix = Mixer(np.zeros(4))
    seg = mix.add(ramp((1,), 0.0, 1.0, 0.1), start_us=20_000)
    f = mix.frame(10_000)
    assert f.targets.tolist() == [0, 0, 0, 0] and not f.started
    f = mix.frame(70_000)  # halfway through the 100 ms ramp
    assert f.targets[1] == pytest.approx(0.5)
    assert f.started == (seg,) and seg.first_frame_us == 70_000
    f = mix.frame(120_000)
    assert f.targets[1] == pytest.approx(1.0) and f.ended == (seg,)
    assert mix.frame(130_000).targets[1] == pytest.approx(1.0)  # held after the end
    assert mix.segments == ()


def test_newer_segment_overrides_and_parent_loop_shows_through_after() -> None:
    mix = Mixer(np.zeros(2))
    parent = mix.add(M((0,), np.array([0.0, 0.1, 0.2]), np.array([[0.0], [1.0], [0.0]]), loop_from=0.0), 0)
    mix.frame(0)
    child = mix.add(ramp((0,), 0.3, 0.3, 0.05), 100_000)
    assert mix.frame(100_000).targets[0] == pytest.approx(0.3)
    f = mix.frame(150_000)
    assert child in f.ended
    # loop position at 0.25 s: 0.25 mod 0.2 = 0.05 -> 0.5
    assert mix.frame(250_000).targets[0] == pytest.approx(0.5)
    assert parent.end_us is None
    mix.release(parent, 300_000)
    f = mix.frame(300_000)
    assert parent in f.ended and parent.last_frame_us == 300_000


def test_cancel_before_start_drops_segment() -> None:
    mix = Mixer(np.zeros(1))
    seg = mix.add(ramp((0,), 0.0, 1.0, 1.0), 500_000)
    mix.cancel(seg)
    assert mix.frame(600_000).targets[0] == 0.0 and mix.segments == ()


def test_rejects_bad_motion() -> None:
    mix = Mixer(np.zeros(2))
    with pytest.raises(ValueError):
        mix.add(ramp((5,), 0.0, 1.0, 1.0), 0)
    with pytest.raises(ValueError):
        mix.add(M((0,), np.array([0.1, 0.2]), np.zeros((2, 1))), 0)
