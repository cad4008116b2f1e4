"""A board's target stream: per servo, where the interpolation starts (its anchor) and where it goes next.

Held by :class:`firmware_sim.board.Board` (``board.stream``). Per servo the anchor is the last applied
keyframe (or where a resumed or restarted servo was): board time us in :attr:`TargetStream.anchor_t`,
target rad in :attr:`TargetStream.anchor_v`; the next keyframe is the jitter buffer's. The arrays are
updated in place for the board's life: the native tick (:mod:`firmware_sim.native`) holds their
addresses, and :meth:`TargetStream.refresh_next` copies the buffer's next keyframes into
``next_ok``/``next_t``/``next_v`` for it. :meth:`TargetStream.interpolate` is the Python reference
of the native interpolation; :meth:`TargetStream.blend` adds the fade from a held command back into
the stream after a hold (:meth:`TargetStream.resume`).
"""

from __future__ import annotations

import numpy as np

from firmware_sim.config import BoardConfig
from firmware_sim.jitter_buffer import JitterBuffer
from robots.motion import min_jerk

__all__ = ["TargetStream", "copy_next"]


def copy_next(nxt: list[tuple[int, float] | None], ok: np.ndarray, nt: np.ndarray, nv: np.ndarray) -> None:
    """The buffer's next keyframe per servo (``JitterBuffer.next_all``: (apply-at µs, rad) or None) into the
    native tick's arrays: ``ok`` 1/0, ``nt`` and ``nv`` (left as they were where there is none)."""
    for i, x in enumerate(nxt):
        if x is None:
            ok[i] = 0
        else:
            ok[i] = 1
            nt[i], nv[i] = x


class TargetStream:
    """The interpolation state of ``n`` servos fed from ``buffer``, starting at ``neutral`` (rad) at time 0;
    ``cfg``: the board's (``resume_speed`` rad/s, ``resume_blend_min_us``)."""

    def __init__(self, n: int, buffer: JitterBuffer, cfg: BoardConfig, neutral: np.ndarray) -> None:
        self.n = n
        self.buffer = buffer
        self.cfg = cfg
        self.anchor_t: np.ndarray = np.zeros(n, dtype=np.int64)
        self.anchor_v: np.ndarray = neutral.astype(np.float64)
        # leaving a hold (see resume, blend): per servo the held command still waiting for its first
        # keyframe, then a minimum-jerk blend of the offset (held - stream) down to 0: start, length, offset
        self._resume_t = 0
        self._resume_from: list[float | None] = [None] * n
        self._blend_t0: list[int] = [0] * n
        self._blend_len: list[int] = [0] * n
        self._blend_off: list[float] = [0.0] * n
        #: a resume blend is still under way (the tick must call :meth:`blend`, not :meth:`interpolate`)
        self.blending = False
        # the buffer's next keyframe per servo as arrays for the native tick (refreshed when the buffer changes)
        self.next_ok = np.zeros(n, dtype=np.int64)
        self.next_t = np.zeros(n, dtype=np.int64)
        self.next_v = np.zeros(n, dtype=np.float64)
        self._next_src: object = None

    def restart(self, i: int, now_us: int, cmd: float) -> None:
        """Servo ``i``'s stream starts again from its command ``cmd`` (rad) at ``now_us`` (FLUSH); no blend."""
        self.anchor_t[i], self.anchor_v[i] = now_us, cmd
        self._resume_from[i], self._blend_off[i] = None, 0.0

    def resume(self, now_us: int, cmd: np.ndarray) -> None:
        """Leaving a hold at ``now_us``: every servo continues from its command ``cmd`` (rad, servo order).

        The host's stream kept its own timeline through the hold, so its next target may be far from
        the held command (a gait phase later). Each servo blends from the held command into the
        stream (:meth:`blend`) instead of ramping to the first keyframe within the lookahead, which
        would step to the speed limit.
        """
        self.anchor_t[:] = now_us
        self.anchor_v[:] = cmd
        self._resume_t = now_us
        self._resume_from = self.anchor_v.tolist()
        self._blend_off = [0.0] * self.n
        self.blending = True

    def blend(self, t: int) -> list[float]:
        """Interpolated targets at ``t`` plus, per servo after a resume, the offset from the held command to
        the stream fading with the minimum-jerk profile 1 - :func:`robots.motion.min_jerk`
        over ``1.875 |offset| / resume_speed`` (the profile's peak speed is 1.875 offset / length).

        A servo waits at its held command until its first keyframe after the resume; from then the
        stream for it is that keyframe's target until it is due, then the frames as usual.
        """
        pend, at, av = self._resume_from, self.anchor_t, self.anchor_v
        nxt = self.buffer.next_all()
        speed, min_len = self.cfg.resume_speed, self.cfg.resume_blend_min_us
        for i, held in enumerate(pend):
            if held is None:
                continue
            first = nxt[i]
            if first is not None:
                v1 = first[1]
                at[i], av[i] = t, v1  # flat at the first target until it is due
            elif at[i] != self._resume_t or av[i] != held:
                v1 = float(av[i])  # a frame was applied at once
            else:
                continue
            pend[i] = None
            off = held - v1
            self._blend_t0[i], self._blend_off[i] = t, off
            self._blend_len[i] = max(min_len, int(1.875 * abs(off) / speed * 1e6))
        out = self.interpolate(t)
        active = any(v is not None for v in pend)
        for i, off in enumerate(self._blend_off):
            if off:
                s = (t - self._blend_t0[i]) / self._blend_len[i]
                if s >= 1.0:
                    self._blend_off[i] = 0.0
                    continue
                out[i] += off * (1.0 - float(min_jerk(np.asarray(s))))
                active = True
        if not active:
            self.blending = False
        for i, held in enumerate(pend):
            if held is not None:
                out[i] = held
        return out

    def interpolate(self, t: int) -> list[float]:
        """Per servo at ``t``: linear from its anchor (last applied keyframe) to its next buffered keyframe.

        The reference for the native tick's interpolation (``firmware_sim/native/tick.c``)."""
        at, av = self.anchor_t.tolist(), self.anchor_v.tolist()
        out = av[:]
        for i, nxt in enumerate(self.buffer.next_all()):
            if nxt is not None:
                t1, v1 = nxt
                t0 = at[i]
                if t1 > t0:
                    a = av[i]
                    out[i] = a + (v1 - a) * (t - t0) / (t1 - t0)
        return out

    def refresh_next(self) -> None:
        """Copy the buffer's next keyframe per servo into the native tick's arrays when it changed
        (the buffer rebuilds its cached list, a new object, after every change)."""
        nxt = self.buffer.next_all()
        if nxt is self._next_src:
            return
        self._next_src = nxt
        copy_next(nxt, self.next_ok, self.next_t, self.next_v)
