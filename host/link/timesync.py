"""Host <-> board clock estimation from NTP-style four-timestamp exchanges.

Each TIME_SYNC exchange gives ``t1`` (host send), ``t2`` (board receive), ``t3``
(board send) and ``t4`` (host receive). Its offset (board - host) is
``((t2 - t1) + (t3 - t4)) / 2`` and its round trip ``(t4 - t1) - (t3 - t2)``; the
offset's error is at most half the round trip (the path asymmetry). Queued
samples (long round trips) are the noisy ones, so the estimator keeps a window
of recent samples, picks those with the smallest round trips and fits
``offset(t) = offset0 + drift * (t - t_ref)`` by least squares (numpy). The drift is
kept only when it stands out of the noise (|drift| > 3 standard errors) and is
plausible (< ``max_drift_ppm``); otherwise, and with fewer than three samples or a
short span, the estimate is the offset alone (drift 0).

Written by hand (about 60 lines) because the usual NTP/PTP libraries are daemons
that discipline the system clock, not estimators one can feed samples.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["ClockEstimate", "ClockSync", "SyncSample", "host_now_us", "quantile_sorted"]


def host_now_us() -> int:
    """The host clock used for time sync: ``time.monotonic`` in integer microseconds."""
    return time.monotonic_ns() // 1000


def quantile_sorted(values: Sequence[float], q: float) -> float:
    """The ``q`` quantile (0..1) of a non-empty ascending list, interpolated linearly between the
    closest ranks: numpy's default method (``np.quantile(values, q)``, Hyndman & Fan's type 7).

    By hand because it sits on the start of every motion and every frame sent (the link's latency):
    ``np.quantile`` took 63 µs a call on a 64-sample window, and its first call 13 ms (it imports
    ``numpy.ma`` lazily), which in CI made a realtime run's first frames late (tests/link/test_paced_link.py).
    Raises ``ValueError`` for an empty list or ``q`` outside 0..1.
    """
    if not values or not 0.0 <= q <= 1.0:
        raise ValueError(f"quantile {q} of {len(values)} values")
    pos = q * (len(values) - 1)
    lo = int(pos)
    hi = min(lo + 1, len(values) - 1)
    return float(values[lo] + (values[hi] - values[lo]) * (pos - lo))


@dataclass(frozen=True)
class SyncSample:
    """One exchange reduced to its midpoint host time, offset and round trip (all us); ``up_us`` is
    ``t2 - t1`` (the host -> board leg plus the clock offset); ``wire_us`` the part of that leg the
    host's model of its line accounts for (waiting behind earlier bytes + the request's own wire
    time, :attr:`host.link.client.BoardClient.tx_wire`; 0 without a model)."""

    host_mid_us: float
    offset_us: float
    rtt_us: float
    up_us: float = 0.0
    wire_us: float = 0.0

    @classmethod
    def from_timestamps(cls, t1: int, t2: int, t3: int, t4: int, wire_up_us: float = 0.0,
                        wire_down_us: float = 0.0) -> SyncSample:
        """Reduce the four timestamps (t1, t4 host clock; t2, t3 board clock).

        The offset is NTP's ``((t2 - t1) + (t3 - t4)) / 2`` (RFC 5905, section 8), which assumes both
        legs take equally long. ``wire_up_us`` / ``wire_down_us``: the modelled wire time of the request's
        leg (its wait behind earlier bytes included) and of the reply's own bytes, taken out of each leg
        before the legs are averaged. Without that, a modelled 115 200-baud line (a 17-byte request,
        1.5 ms; a 34-byte reply, 3.0 ms) put the board clock estimate 0.7 ms behind the board's: every
        board time the host stamped (a token's arrival on the run's timeline) read early by that much.
        The round trip keeps the wire time (it ranks the samples)."""
        up, down = (t2 - t1) - wire_up_us, (t4 - t3) - wire_down_us
        return cls((t1 + t4) / 2.0, (up - down) / 2.0, float((t4 - t1) - (t3 - t2)), float(t2 - t1), wire_up_us)


@dataclass(frozen=True)
class ClockEstimate:
    """board_us = host_us + offset_us + drift * (host_us - ref_host_us), +- uncertainty_us."""

    offset_us: float
    drift: float  # dimensionless (1e-6 = 1 ppm): board seconds gained per host second
    ref_host_us: float
    uncertainty_us: float
    samples_used: int
    min_rtt_us: float

    @property
    def drift_ppm(self) -> float:
        return self.drift * 1e6

    def host_to_board(self, t_host_us: float) -> int:
        return int(round(t_host_us + self.offset_us + self.drift * (t_host_us - self.ref_host_us)))

    def board_to_host(self, t_board_us: float) -> int:
        # invert board = host*(1+d) + offset - d*ref
        return int(round((t_board_us - self.offset_us + self.drift * self.ref_host_us) / (1.0 + self.drift)))


class ClockSync:
    """Windowed offset + drift estimator (least squares over the lowest-round-trip samples)."""

    def __init__(
        self, window: int = 64, best_fraction: float = 0.5, min_span_us: float = 200_000.0, max_drift_ppm: float = 1000.0
    ) -> None:
        self._samples: deque[SyncSample] = deque(maxlen=window)
        self.max_drift = max_drift_ppm * 1e-6
        self.best_fraction = best_fraction
        self.min_span_us = min_span_us  # below this host-time span the drift is not fitted
        self._estimate: ClockEstimate | None = None
        self._uplinks: list[float] | None = None  # ascending, for the current estimate (uplink_quantile)

    def __len__(self) -> int:
        return len(self._samples)

    def clear(self) -> None:
        """Forget every sample (after a reconnect the board clock may have restarted)."""
        self._samples.clear()
        self._estimate = None
        self._uplinks = None

    def add(self, t1: int, t2: int, t3: int, t4: int, wire_us: float = 0.0, wire_down_us: float = 0.0) -> ClockEstimate | None:
        """Add one exchange and refit; samples with a negative round trip are ignored. ``wire_us``: the
        modelled wire time of the request's leg, ``wire_down_us`` of the reply's (see
        :meth:`SyncSample.from_timestamps`)."""
        s = SyncSample.from_timestamps(t1, t2, t3, t4, max(0.0, float(wire_us)), max(0.0, float(wire_down_us)))
        if s.rtt_us < 0:
            return self._estimate
        self._samples.append(s)
        self._estimate = self._fit()
        self._uplinks = None
        return self._estimate

    @property
    def estimate(self) -> ClockEstimate | None:
        return self._estimate

    def uplink_quantile(self, q: float) -> float | None:
        """The ``q`` quantile of the host -> board latency (µs) over the window: ``t2 - t1`` minus the
        estimated offset, None before an estimate. Measured against the same offset that maps host
        time to board time, so ``host_to_board(now) + uplink_quantile(q)`` is when a message sent
        now reaches the board, even when the path is asymmetric (the offset's bias cancels).

        Samples that carry a modelled ``wire_us`` count without it: the quantile is then the latency
        beyond the line (OS, pty, the board's reaction), and the sender adds the line's present
        backlog and its message's own wire time (:meth:`host.motion.board_link.BoardFrameLink.latency_us`)."""
        est = self._estimate
        if est is None or not self._samples:
            return None
        if self._uplinks is None:  # once per new sample: this is asked on every frame sent and every start
            self._uplinks = sorted(s.up_us - s.wire_us - (est.offset_us + est.drift * (s.host_mid_us - est.ref_host_us))
                                   for s in self._samples)
        return max(0.0, quantile_sorted(self._uplinks, q))

    def rtt_quantile(self, q: float) -> float | None:
        """The ``q`` quantile (0..1) of the round trips in the window (µs), None without samples."""
        if not self._samples:
            return None
        return quantile_sorted(sorted(s.rtt_us for s in self._samples), q)

    def _fit(self) -> ClockEstimate:
        samples = sorted(self._samples, key=lambda s: s.rtt_us)
        keep = samples[: max(1, int(np.ceil(len(samples) * self.best_fraction)))]
        t = np.array([s.host_mid_us for s in keep])
        y = np.array([s.offset_us for s in keep])
        min_rtt = float(keep[0].rtt_us)
        ref = float(t.mean())
        span = float(t.max() - t.min()) if len(keep) > 1 else 0.0
        if len(keep) >= 3 and span >= self.min_span_us:
            a = np.vstack([np.ones_like(t), t - ref]).T
            (off, drift), *_ = np.linalg.lstsq(a, y, rcond=None)
            resid = y - (off + drift * (t - ref))
            dof = max(1, len(keep) - 2)
            sxx = float(np.sum((t - ref) ** 2))
            se = float(np.sqrt(np.sum(resid**2) / dof / sxx)) if sxx > 0 else float("inf")
            if abs(drift) < 3.0 * se or abs(drift) > self.max_drift:
                # not distinguishable from noise (or implausible for a crystal): offset only
                off, drift = float(np.mean(y)), 0.0
                resid = y - off
                dof = max(1, len(keep) - 1)
        else:
            off, drift = float(np.mean(y)), 0.0
            resid = y - off
            dof = max(1, len(keep) - 1)
        sigma = float(np.sqrt(np.sum(resid**2) / dof)) if len(keep) > 1 else 0.0
        # path asymmetry bound (half the best round trip) plus the scatter around the fit
        unc = min_rtt / 2.0 + 2.0 * sigma
        return ClockEstimate(float(off), float(drift), ref, unc, len(keep), min_rtt)
