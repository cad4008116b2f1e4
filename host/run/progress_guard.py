"""The no-progress guard: a session whose work stops moving for a bounded wall time ends, and says on what.

A run can wait on something that neither telemetry nor a deadline ends: a lockstep board held still for
an LLM chunk that never comes (the silence watchdog exempts a held board), a segment whose end is never
confirmed, a cleanup that waits for a board time the host no longer streams towards. The guard watches
what the session's work moves while it is armed (a turn, the start pose, the rest pose):

* ``board time``: the board time of the last telemetry report the host handled (seconds);
* ``frames``: servo frames the link wrote;
* ``calls``: how many of the turn's calls have started and ended;
* ``phase``: what the session is doing (``"moving to the start pose"``, ``"running the turn"``, ...).

When none of them changed for ``limit_s`` wall seconds it calls ``on_stall`` once with a
:class:`Stall` (the one line names the phase and what it was waiting for) and returns. A gap in which the
guard itself did not run (the process was starved or suspended for more than ``STARVED_S``) is not
counted as no progress, as the silence watchdog does (:data:`host.run.pump.STALL_S`).

The guard only reads the probes: it needs no link, and tests drive it with a virtual clock and sleep.
"""

from __future__ import annotations

import time
from collections.abc import Awaitable, Callable, Hashable, Mapping
from dataclasses import dataclass

import anyio

__all__ = ["CHECK_S", "PROGRESS_LIMIT_S", "STARVED_S", "ProgressGuard", "Stall"]

#: wall seconds without any progress after which a session's work is taken as stalled. Longer than every
#: wait that has its own deadline and message, so the guard only ends what nothing else would: the silence
#: watchdog's 10 s (:data:`host.run.pump.TELEMETRY_SILENCE_S`), an MCP tool call's 30 s
#: (``host.mounts.mcp_mount`` ``call_timeout``) and an LLM request's 60 s (``host.ghost`` ``timeout_s``).
PROGRESS_LIMIT_S = 90.0
#: wall seconds between two looks at the probes
CHECK_S = 0.25
#: a look that comes this much later than asked for means the process did not run: the gap is not counted
STARVED_S = 1.0


@dataclass(frozen=True)
class Stall:
    """What a stalled session was doing: ``phase`` (e.g. ``"running the turn"``), ``waiting_for`` (e.g.
    ``"wait[0]/pick[0] to end"``), ``waited_s`` wall seconds without progress, and the probes' last values."""

    phase: str
    waiting_for: str
    waited_s: float
    last: Mapping[str, Hashable]

    @property
    def message(self) -> str:
        """One line: ``"no progress for 30 s while running the turn, waiting for ...: board time 10.500 s, ..."``."""
        seen = ", ".join(f"{k} {_show(v)}" for k, v in self.last.items() if k != "phase")
        return (f"no progress for {self.waited_s:.0f} s of wall time while {self.phase}, waiting for "
                f"{self.waiting_for} ({seen} unchanged)")


def _show(v: Hashable) -> str:
    return f"{v:.3f} s" if isinstance(v, float) else str(v)


class ProgressGuard:
    """Calls ``on_stall`` once when the probes stop changing for ``limit_s`` wall seconds while armed.

    ``probes``: name -> zero-argument callable returning a hashable value (compared with ``!=``);
    ``phase()`` names what the session is doing, None while there is nothing to guard (between turns,
    a chat waiting for its user): the guard is then disarmed and the wait starts again when it is armed;
    ``waiting_for()`` names what the phase waits for (read only when stalled). ``clock``/``sleep``: wall
    seconds (tests pass a virtual pair).
    """

    def __init__(self, probes: Mapping[str, Callable[[], Hashable]], phase: Callable[[], str | None],
                 waiting_for: Callable[[], str], on_stall: Callable[[Stall], None], *,
                 limit_s: float = PROGRESS_LIMIT_S, check_s: float = CHECK_S,
                 clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], Awaitable[None]] = anyio.sleep) -> None:
        if not limit_s > 0 or not check_s > 0:
            raise ValueError(f"limit_s and check_s must be > 0, got {limit_s!r} and {check_s!r}")
        self.probes, self.phase, self.waiting_for, self.on_stall = probes, phase, waiting_for, on_stall
        self.limit_s, self.check_s, self.clock, self.sleep = limit_s, check_s, clock, sleep
        #: the stall reported (None while none was)
        self.stall: Stall | None = None

    def _look(self) -> dict[str, Hashable]:
        return {"phase": self.phase(), **{name: probe() for name, probe in self.probes.items()}}

    async def run(self) -> Stall:
        """Watch until the work stalls; report it (``on_stall``) and return it. Cancel to stop watching."""
        last = self._look()
        since = woke = self.clock()
        while True:
            await self.sleep(self.check_s)
            now = self.clock()
            late = now - woke - self.check_s
            woke = now
            if late > STARVED_S:  # the process did not run: no one could have made progress
                since += late
            seen = self._look()
            if seen != last or seen["phase"] is None:
                last, since = seen, now
                continue
            if now - since >= self.limit_s:
                self.stall = Stall(str(seen["phase"]), self.waiting_for(), now - since,
                                   {k: v for k, v in seen.items()})
                self.on_stall(self.stall)
                return self.stall
