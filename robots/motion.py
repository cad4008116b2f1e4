"""Generic motion maths for any robot: the ``Motion`` contract, minimum jerk, a sequencer, transitions.

A :class:`Motion` is what the host's motion mixer plays on one channel: sample times, joint targets
for some servos (radians, the servo table's joint angles) and, for the persistent form of a
behaviour, the time a seamless loop starts. The board interpolates linearly between samples, so the
speed a motion demands of a servo is its largest finite difference; every motion built here
satisfies the robot's joint limits and speed limits (:class:`JointLimits`; :meth:`Track.build` enforces
the speed limits by uniform time stretching as a last resort).

Minimum-jerk segments are written by hand (one polynomial, Flash & Hogan 1985): no maintained
library offers exactly "min-jerk under a per-joint speed limit, sampled on a grid", and the formula
is five lines.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Self, TypeVar

import numpy as np

from robots.datatypes import RobotData, ServoTable

__all__ = [
    "DT",
    "EASE_IN_S",
    "JointLimits",
    "Motion",
    "SPEED_MARGIN",
    "Track",
    "check_choice",
    "check_count",
    "check_finite",
    "check_start",
    "ease_in",
    "min_jerk",
    "transition",
]


@dataclass(frozen=True, eq=False)
class JointLimits:
    """Per-servo joint limits and speed limits of one robot (radians, rad/s; servo order).

    ``neutral`` fills the servos a partial start vector leaves out; ``names`` are the servo names
    (for messages).
    """

    lo: np.ndarray
    hi: np.ndarray
    vmax: np.ndarray
    neutral: np.ndarray
    names: tuple[str, ...]

    @classmethod
    def of(cls, table: ServoTable) -> JointLimits:
        """The limits of a servo table."""
        return cls(np.array(table.mins), np.array(table.maxs), np.array(table.max_speeds),
                   np.array(table.neutral), table.names)

    @classmethod
    def of_robot(cls, robot: RobotData) -> JointLimits:
        """The limits of ``robot``'s servo table (cached on the robot)."""
        cached = robot.__dict__.get("_limits")
        if cached is None:
            cached = cls.of(robot.servos)
            robot.__dict__["_limits"] = cached
        return cached  # type: ignore[no-any-return]

    @property
    def n(self) -> int:
        """How many servos."""
        return len(self.lo)


def check_start(start: Sequence[float] | np.ndarray, limits: JointLimits) -> np.ndarray:
    """Validate the current joint targets of all servos (within limits, finite); clipped copy."""
    s = np.asarray(start, dtype=float)
    if s.shape != (limits.n,):
        raise ValueError(f"start must hold {limits.n} joint targets (radians), got shape {s.shape}")
    if not np.all(np.isfinite(s)):
        raise ValueError("start holds a non-finite joint target")
    bad = np.flatnonzero((s < limits.lo - 1e-6) | (s > limits.hi + 1e-6))
    if bad.size:
        raise ValueError("start is outside the joint limits for " + ", ".join(limits.names[i] for i in bad))
    return np.clip(s, limits.lo, limits.hi)


T = TypeVar("T")

#: Sample period of generated motions (s): the mixer's default frame rate is 100 Hz.
DT = 0.01
#: Fraction of each servo's max speed a motion may use (headroom for the board's interpolation).
SPEED_MARGIN = 0.85
#: Peak velocity of a minimum-jerk move of unit amplitude over unit time.
_MJ_PEAK = 1.875


@dataclass(frozen=True)
class Motion:
    """A trajectory for one channel's servos.

    ``servos``: 0-based servo indices (servo id - 1); ``t``: (N,) seconds from the motion start,
    strictly increasing, ``t[0] == 0``; ``q``: (N, len(servos)) joint targets in radians;
    ``loop_from``: persistent form only, after ``t[-1]`` the part ``[loop_from, t[-1]]`` repeats
    until released (the sample at ``loop_from`` equals the last one, so the loop is seamless).
    """

    servos: tuple[int, ...]
    t: np.ndarray
    q: np.ndarray
    loop_from: float | None = None

    @property
    def duration(self) -> float:
        """Length of the motion (s): ``t[-1]`` (one pass, loops excluded)."""
        return float(self.t[-1])

    def at(self, time: float | np.ndarray) -> np.ndarray:
        """Targets at ``time`` (s), linearly interpolated; looping after the end when ``loop_from`` is set."""
        tt = np.asarray(time, dtype=float)
        if self.loop_from is not None and self.t[-1] > self.loop_from:
            period = self.t[-1] - self.loop_from
            tt = np.where(tt > self.t[-1], self.loop_from + np.mod(tt - self.loop_from, period), tt)
        cols = [np.interp(tt, self.t, self.q[:, j]) for j in range(len(self.servos))]
        return np.stack(cols, axis=-1)


def min_jerk(s: np.ndarray) -> np.ndarray:
    """Minimum-jerk blend 10s^3 - 15s^4 + 6s^5 of a normalised time ``s`` in [0, 1]."""
    s = np.clip(s, 0.0, 1.0)
    return s**3 * (10.0 - 15.0 * s + 6.0 * s * s)


def _grid(duration: float) -> np.ndarray:
    """Normalised sample points (excluding 0, including 1) for a segment of ``duration`` seconds."""
    n = max(1, math.ceil(duration / DT - 1e-9))
    return np.arange(1, n + 1) / n


class Track:
    """Builds one channel's motion sample by sample, starting from the current targets.

    ``start``: the targets of all servos (``limits.n``) or of ``servos`` only.

    Samples are kept as blocks (one array per :meth:`move` / :meth:`samples` call) and joined once
    by :meth:`build`: compiling a behaviour is on the token -> servo path of a motion that starts at
    once, and a Python append per sample cost ~3 us (a 700-sample walk: ~2 ms).
    """

    def __init__(self, servos: Sequence[int], start: np.ndarray, limits: JointLimits) -> None:
        self.servos = tuple(int(i) for i in servos)
        sel = list(self.servos)
        self.lo, self.hi, self.vmax = limits.lo[sel], limits.hi[sel], limits.vmax[sel]
        q0 = np.asarray(start, dtype=float)
        if q0.shape == (limits.n,) and len(self.servos) != limits.n:
            q0 = q0[list(self.servos)]
        q0 = q0.copy()
        self._t: list[np.ndarray] = [np.zeros(1)]  # sample times (s), one block per call
        self._q: list[np.ndarray] = [q0[None, :]]  # targets (k, n), one block per call
        self._now = 0.0
        self._last = q0
        self.loop_from: float | None = None

    def _append(self, t: np.ndarray, q: np.ndarray) -> None:
        """Append samples at times ``t`` (k,) with targets ``q`` (k, n) (``q`` is kept, not copied)."""
        if len(t):
            self._t.append(t)
            self._q.append(q)
            self._now = float(t[-1])
            self._last = q[-1]

    @property
    def now(self) -> float:
        return self._now

    @property
    def q(self) -> np.ndarray:
        """The last target."""
        return self._last.copy()

    def min_time(self, target: np.ndarray, speed: float | np.ndarray | None = None) -> float:
        """Shortest min-jerk duration from the last target to ``target`` within the speed limit."""
        v = self.vmax * SPEED_MARGIN if speed is None else np.minimum(self.vmax * SPEED_MARGIN, speed)
        return float(np.max(_MJ_PEAK * np.abs(np.asarray(target) - self._last) / v))

    def move(self, target: Sequence[float] | np.ndarray, duration: float = 0.0,
             speed: float | np.ndarray | None = None) -> Self:
        """Min-jerk move to ``target`` taking ``duration`` s or longer if the speed limit needs it."""
        goal = np.clip(np.asarray(target, dtype=float), self.lo, self.hi)
        dur = max(duration, self.min_time(goal, speed))
        if dur <= 1e-9:
            return self
        q0, t0 = self.q, self.now
        s = _grid(dur)
        q = q0 + (goal - q0) * min_jerk(s)[:, None]
        q[-1] = goal
        self._append(t0 + s * dur, q)
        return self

    def hold(self, duration: float) -> Self:
        """Keep the last target for ``duration`` s."""
        if duration > 1e-9:
            self._append(np.array([self.now + duration]), self.q[None, :])
        return self

    def samples(self, dt: float, q: np.ndarray) -> Self:
        """Append samples ``q`` (k, n) spaced ``dt`` apart after the last one."""
        if not dt > 0:
            raise ValueError(f"sample spacing must be > 0 s, got {dt}")
        rows = np.clip(np.asarray(q, dtype=float), self.lo, self.hi)
        self._append(self.now + np.arange(1, len(rows) + 1) * dt, rows)
        return self

    def cycle(self, fn: Callable[[np.ndarray], np.ndarray], period: float, cycles: int = 1) -> Self:
        """Append ``cycles`` periods of ``fn(phase) -> (k, n)`` absolute targets (phase in [0, 1)).

        The track first moves to ``fn(0)`` if it is elsewhere; the sample at each period's end equals
        ``fn(0)`` exactly, so a loop marked at a period's start is seamless.
        """
        first = np.clip(fn(np.zeros(1))[0], self.lo, self.hi)
        self.move(first)
        n = max(4, round(period / DT))
        phase = np.arange(1, n + 1) / n
        one = np.clip(fn(np.mod(phase, 1.0)), self.lo, self.hi)
        one[-1] = first
        for _ in range(max(0, cycles)):
            self.samples(period / n, one)
        return self

    def mark_loop(self) -> Self:
        """The persistent form loops from here to the end."""
        self.loop_from = self.now
        return self

    def build(self, hold_end: bool = False) -> Motion:
        """The motion; ``hold_end`` marks the last sample as a held loop (persistent posture)."""
        if len(self._t) < 2:
            self.hold(DT)
        t = np.concatenate(self._t)
        q = np.clip(np.concatenate(self._q), self.lo, self.hi)
        loop = float(t[-1]) if hold_end else self.loop_from
        # last resort: stretch time uniformly so no step exceeds the speed limit
        dq = np.abs(np.diff(q, axis=0)) / np.diff(t)[:, None]
        ratio = float(np.max(dq / self.vmax)) if len(dq) else 0.0
        if ratio > 1.0:
            scale = ratio * 1.001
            t = t * scale
            loop = None if loop is None else loop * scale
        return Motion(self.servos, t, q, loop)


def transition(start: Sequence[float] | np.ndarray, target: Sequence[float] | np.ndarray,
               servos: Sequence[int], limits: JointLimits, *, max_speed: float | None = None,
               min_duration: float = 0.0) -> Motion:
    """Smooth min-jerk move of ``servos`` from ``start`` to ``target`` within ``limits``.

    ``start`` holds all servos' targets (or one per servo in ``servos``); ``target`` likewise. Each
    servo stays under its table speed limit (times a safety margin) and under ``max_speed``
    (rad/s) when given; the move takes at least ``min_duration`` s. A start outside the joint
    limits is clipped to them (a reset must never fail), so only then the first sample differs.
    """
    n = limits.n
    servos = tuple(int(i) for i in servos)
    if not servos or any(not 0 <= i < n for i in servos):
        raise ValueError(f"servos must be indices 0..{n - 1}, got {servos}")
    if max_speed is not None and not max_speed > 0:
        raise ValueError(f"max_speed must be > 0 rad/s, got {max_speed}")
    tgt = np.asarray(target, dtype=float)
    if tgt.shape == (n,) and len(servos) != n:
        tgt = tgt[list(servos)]
    if tgt.shape != (len(servos),) or not np.all(np.isfinite(tgt)):
        raise ValueError(f"target must hold {len(servos)} or {n} finite joint angles")
    st = np.asarray(start, dtype=float)
    if st.shape == (len(servos),) and len(servos) != n:
        full = limits.neutral.copy()
        full[list(servos)] = st
        st = full
    if st.shape != (n,) or not np.all(np.isfinite(st)):
        raise ValueError(f"start must hold {len(servos)} or {n} finite joint angles")
    st = np.clip(st, limits.lo, limits.hi)
    return Track(servos, st, limits).move(tgt, min_duration, max_speed).build()


def check_finite(**values: float) -> None:
    """Raise a clear ValueError unless every value is a finite number."""
    for k, v in values.items():
        if not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ValueError(f"{k} must be a finite number, got {v!r}")


def check_count(times: int) -> int:
    """A repetition count >= 1 (clear ValueError otherwise)."""
    if isinstance(times, bool) or not isinstance(times, (int, float)) or not math.isfinite(times) or times < 1:
        raise ValueError(f"times must be a whole number >= 1, got {times!r}")
    return int(round(times))


def check_choice(value: str, options: dict[str, T], what: str) -> T:
    """``options[value]``, or a ValueError listing the valid values."""
    try:
        return options[value]
    except (KeyError, TypeError):
        raise ValueError(f"unknown {what} {value!r}; valid: {', '.join(options)}") from None


#: Length (s) of the minimum-jerk start :func:`ease_in` gives a motion that starts from rest.
EASE_IN_S = 0.04


def ease_in(motion: Motion, ramp: float = EASE_IN_S) -> Motion:
    """``motion`` started from rest: its clock accelerates with a minimum-jerk profile over ``ramp`` s.

    The time warp ``w`` has ``w'(t) = min_jerk(t / ramp)`` for ``t < ramp`` and ``1`` after, so the
    motion is played ``ramp / 2`` s later overall, never faster than planned (speed limits hold), and
    its first targets stay almost at the start pose (the first 10 ms move less than 3 % of what the
    original's first 10 ms did): a first frame that reaches the board late cannot jerk. Looping
    motions whose loop begins inside the ramp are returned unchanged (the loop must stay seamless).
    """
    if ramp <= 0 or (motion.loop_from is not None and motion.loop_from < ramp):
        return motion
    shift = ramp / 2.0  # integral of min_jerk over [0, 1] is 1/2
    n = max(2, math.ceil(ramp / DT - 1e-9) + 1)
    tr = np.linspace(0.0, ramp, n)
    u = tr / ramp  # w(t) = ramp * integral_0^u min_jerk = ramp * (2.5u^4 - 3u^5 + u^6)
    warped = ramp * (2.5 * u**4 - 3.0 * u**5 + u**6)
    rest_t = motion.t[motion.t > ramp - shift]
    t_new = np.concatenate([tr, rest_t + shift])
    q_new = np.concatenate([motion.at(warped), motion.q[motion.t > ramp - shift]])
    loop = None if motion.loop_from is None else motion.loop_from + shift
    return Motion(motion.servos, t_new, q_new, loop)
