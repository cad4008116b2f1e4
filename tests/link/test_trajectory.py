"""Min-jerk trajectories: exact endpoints, smooth ends, speed limits respected by stretching."""

from __future__ import annotations

import numpy as np
import pytest

from host.motion.trajectory import PEAK_SPEED_FACTOR, min_jerk, min_jerk_duration
from robots.coco import load_poses, load_servo_table


def test_endpoints_sampling_and_smooth_ends() -> None:
    q0 = np.array([0.0, 1.0, -0.5])
    q1 = np.array([0.5, 0.0, -0.5])
    t, q = min_jerk(q0, q1, 1.0, 100.0, max_speed=[10.0, 10.0, 10.0])
    assert t[0] == 0.0 and t[-1] == pytest.approx(1.0) and len(t) == 101
    assert np.allclose(np.diff(t), 0.01)
    assert np.array_equal(q[0], q0) and np.array_equal(q[-1], q1)
    v = np.diff(q, axis=0) / np.diff(t)[:, None]
    assert np.all(np.abs(v[0]) < 0.01) and np.all(np.abs(v[-1]) < 0.01)  # starts and ends at rest
    assert np.all(q[:, 2] == -0.5)  # a servo that does not move stays put
    mid = q[50]
    assert np.allclose(mid, (q0 + q1) / 2)  # symmetric profile


def test_duration_is_stretched_to_the_slowest_servo() -> None:
    q0, q1 = np.zeros(2), np.array([2.0, 0.1])
    speeds = np.array([1.0, 10.0])
    T = min_jerk_duration(q0, q1, 0.5, speeds)
    assert T == pytest.approx(PEAK_SPEED_FACTOR * 2.0 / 1.0)
    t, q = min_jerk(q0, q1, 0.5, 200.0, max_speed=speeds)
    assert t[-1] == pytest.approx(T)
    v = np.abs(np.diff(q, axis=0) / np.diff(t)[:, None])
    assert np.all(v <= speeds * (1 + 1e-6))
    assert v[:, 0].max() > 0.95 * speeds[0]  # not slower than needed


def test_coco_speed_limits_apply_by_default() -> None:
    table = load_servo_table()
    poses = load_poses()
    t, q = min_jerk(poses["sit"], poses["crouch"], 0.05, 500.0)  # far too fast if not stretched
    v = np.abs(np.diff(q, axis=0) / np.diff(t)[:, None])
    assert t[-1] > 0.05
    assert np.all(v <= np.array(table.max_speeds) * (1 + 1e-6))


def test_zero_move_and_bad_input() -> None:
    t, q = min_jerk([0.1, 0.2], [0.1, 0.2], 0.0, 100.0, max_speed=[1.0, 1.0])
    assert len(t) == 1 and np.allclose(q, [[0.1, 0.2]])
    with pytest.raises(ValueError):
        min_jerk([0.0], [1.0, 2.0], 1.0, 100.0)
    with pytest.raises(ValueError):
        min_jerk([0.0], [1.0], 1.0, 0.0)
    with pytest.raises(ValueError):
        min_jerk_duration([0.0], [1.0], -1.0)
