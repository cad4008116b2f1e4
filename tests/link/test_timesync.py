"""The clock estimator recovers a known offset and drift from synthetic NTP samples."""

from __future__ import annotations

import numpy as np
import pytest

from hypothesis import given
from hypothesis import strategies as st

from host.link.timesync import ClockSync, SyncSample, quantile_sorted


def _exchange(rng: np.random.Generator, t1: float, offset: float, drift: float, queued: bool) -> tuple[int, int, int, int]:
    """One exchange against a board clock board(h) = h + offset + drift * h, with random path delays."""
    up = rng.uniform(80, 120) + (rng.uniform(2_000, 20_000) if queued else 0.0)
    down = rng.uniform(80, 120) + (rng.uniform(2_000, 20_000) if queued and rng.random() < 0.5 else 0.0)
    turn = rng.uniform(5, 50)
    h2 = t1 + up
    h3 = h2 + turn
    t4 = h3 + down

    def board(h: float) -> float:
        return h + offset + drift * h

    return int(t1), int(round(board(h2))), int(round(board(h3))), int(t4)


def test_sample_reduction_matches_ntp_formulas() -> None:
    s = SyncSample.from_timestamps(1000, 6100, 6150, 1300)
    assert s.rtt_us == 250
    assert s.offset_us == ((6100 - 1000) + (6150 - 1300)) / 2


def test_recovers_offset_and_drift_despite_queued_samples() -> None:
    rng = np.random.default_rng(7)
    offset, drift = 5_000_000.0, 80e-6  # 5 s apart, board runs 80 ppm fast
    sync = ClockSync(window=64)
    for k in range(64):
        sync.add(*_exchange(rng, 1e6 + k * 50_000.0, offset, drift, queued=rng.random() < 0.4))
    est = sync.estimate
    assert est is not None
    assert est.drift_ppm == pytest.approx(80.0, abs=5.0)
    for h in (1e6, 2.5e6, 4e6):
        truth = h + offset + drift * h
        assert abs(est.host_to_board(h) - truth) <= max(est.uncertainty_us, 1.0)
        assert abs(est.board_to_host(truth) - h) <= max(est.uncertainty_us, 1.0) + 1
    assert est.uncertainty_us < 200  # best samples have ~200 us round trips
    assert est.min_rtt_us < 300


def test_a_single_sample_gives_offset_only_and_bounds_it_by_half_the_rtt() -> None:
    sync = ClockSync()
    est = sync.add(1_000, 10_100, 10_120, 1_300)
    assert est is not None and est.drift == 0.0 and est.samples_used == 1
    assert est.uncertainty_us == pytest.approx(est.min_rtt_us / 2)
    assert abs(est.host_to_board(1_150) - 10_110) <= est.uncertainty_us


def test_window_is_bounded_and_clear_forgets() -> None:
    sync = ClockSync(window=8)
    for k in range(100):
        sync.add(k * 1000, k * 1000 + 50, k * 1000 + 60, k * 1000 + 110)
    assert len(sync) == 8
    sync.clear()
    assert len(sync) == 0 and sync.estimate is None


def test_negative_round_trip_is_ignored() -> None:
    sync = ClockSync()
    assert sync.add(1000, 5000, 9000, 1100) is None  # board claims 4 ms turnaround inside a 0.1 ms round trip
    assert len(sync) == 0


def test_noisy_samples_without_drift_do_not_invent_one() -> None:
    rng = np.random.default_rng(3)
    sync = ClockSync(window=32)
    for k in range(32):  # 2 s of exchanges whose down path queues 0..8 ms behind other traffic
        t1 = 1e6 + k * 60_000.0
        down = 4_000 + rng.uniform(0, 8_000)
        sync.add(int(t1), int(t1 + 2_100 + 1_000_000), int(t1 + 2_110 + 1_000_000), int(t1 + 2_110 + down))
    est = sync.estimate
    assert est is not None and est.drift == 0.0
    assert abs(est.host_to_board(2e6) - (2e6 + 1_000_000)) <= est.uncertainty_us


def test_uplink_quantile_cancels_the_offset_bias_of_an_asymmetric_path() -> None:
    """Up leg 1 ms (+0..0.5 ms), down leg 6 ms: the offset estimate is biased by the asymmetry, but
    host_to_board(t) + uplink p99 is when a message sent at t reaches the board."""
    true_offset = 5_000_000.0
    sync = ClockSync()
    assert sync.uplink_quantile(0.99) is None
    for k in range(64):
        t1 = 1_000_000 + k * 50_000
        up = 1_000 + (k % 11) * 50
        t2 = int(t1 + true_offset + up)
        t3 = t2 + 20
        t4 = int(t3 - true_offset + 6_000)
        sync.add(t1, t2, t3, t4)
    est = sync.estimate
    assert est is not None and abs(est.offset_us - true_offset) > 2_000  # biased by the asymmetry
    send = 5_000_000
    arrival = est.host_to_board(send) + sync.uplink_quantile(0.99)
    assert abs(arrival - (send + true_offset + 1_500)) < 100


@given(st.lists(st.floats(-1e7, 1e7, allow_nan=False), min_size=1, max_size=80), st.floats(0.0, 1.0))
def test_quantile_sorted_is_numpys_default_quantile(values: list[float], q: float) -> None:
    """The hand-written quantile on the hot path (uplink latency) agrees with ``np.quantile``."""
    ordered = sorted(values)
    assert quantile_sorted(ordered, q) == pytest.approx(float(np.quantile(values, q)), rel=1e-9, abs=1e-6)


def test_quantile_sorted_refuses_what_has_no_quantile() -> None:
    with pytest.raises(ValueError):
        quantile_sorted([], 0.5)
    with pytest.raises(ValueError):
        quantile_sorted([1.0], 1.5)


def test_the_uplink_quantile_follows_every_new_sample() -> None:
    """The sorted uplinks are kept between samples (asked on every frame sent): a new sample must
    replace them, or the margin would stay where the first call left it."""
    cs = ClockSync()
    for i in range(8):
        t1 = 1_000_000 + i * 20_000
        cs.add(t1, t1 + 500, t1 + 600, t1 + 1_100)  # 500 us up, 500 us down
    before = cs.uplink_quantile(0.99)
    t1 = 2_000_000
    cs.add(t1, t1 + 9_500, t1 + 9_600, t1 + 10_100)  # a slow uplink (a long round trip)
    after = cs.uplink_quantile(0.99)
    assert before is not None and after is not None and after > before + 1_000
    cs.clear()
    assert cs.uplink_quantile(0.99) is None
