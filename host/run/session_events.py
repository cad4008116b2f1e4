"""A session's events (:mod:`host.run.events`): watched on every report, handled as the policy says.

:class:`SessionEvents` feeds each TELEMETRY (with the latest SIM_STATE and the link's loss counts) to
an :class:`~host.run.events.EventMonitor`, plays a run's scripted events at their board times, and
handles every event: a fall first interrupts every motion channel, whatever the policy; then
``ignore`` drops it, ``note`` adds it to the running turn's observations (or the next one's), and
``interrupt`` also cuts the running turn. It reaches the shell only through a getter (the shell is
built after the events are wired) and the link only through what a report carries.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING, Any

from host.run.events import Event, EventMonitor, EventPolicy, ScriptedEvent
from robots.generic import GENERIC_CHANNEL

if TYPE_CHECKING:
    from host.link import BoardClient
    from host.motion.streamer import FrameStreamer
    from host.shell import Shell

log = logging.getLogger("host.run")

__all__ = ["SessionEvents"]

#: events kept for :attr:`SessionEvents.events` (newest last)
MAX_KEPT = 256


class SessionEvents:
    """The events of one session (see the module docstring).

    ``robot_channels``: the robot's motion channels (a fall interrupts them and the generic one);
    ``shell()``: the session's shell, None before it exists.
    """

    def __init__(self, policy: EventPolicy, robot_channels: Iterable[str], shell: Callable[[], Shell | None]) -> None:
        self.policy = policy
        self._motion = frozenset(robot_channels) | {GENERIC_CHANNEL}
        self._shell = shell
        #: events handled so far (not the ignored ones), newest last, bounded (:data:`MAX_KEPT`)
        self.events: deque[Event] = deque(maxlen=MAX_KEPT)
        #: called with every event that is not ignored, and its action ("note" | "interrupt")
        self.on_event: list[Callable[[Event, str], None]] = []
        self._turn: list[Event] = []  # events during the running turn (or since the last one)
        self._interrupted_by: Event | None = None
        self._monitor: EventMonitor | None = None
        self._client: BoardClient | None = None

    def watch(self, monitor: EventMonitor, client: BoardClient) -> None:
        """Start watching ``client``'s reports with ``monitor`` (:meth:`on_report` does nothing before)."""
        self._monitor, self._client = monitor, client

    def on_report(self, tel: Any) -> None:
        """Feed one TELEMETRY (``board_time_us``, ``positions``, ``efforts``, ``velocities``) to the monitor."""
        if self._monitor is None or self._client is None:
            return
        sim = self._client.latest_sim_state
        stats = self._client.stats
        base = (sim.base_pos, sim.base_quat) if sim is not None else None
        for ev in self._monitor.feed(tel.board_time_us * 1e-6, tel.positions, base,
                                     toppled=sim.toppled if sim is not None else 0,
                                     losses=stats.decode_errors + stats.retries + stats.seq_gaps,
                                     efforts=tel.efforts, velocities=tel.velocities):
            self.emit(ev)

    async def play(self, streamer: FrameStreamer, t0: float, events: Iterable[ScriptedEvent]) -> None:
        """Emit each scripted event when board time reaches ``t0 + at_s`` (seconds)."""
        for ev in events:
            await streamer.wait_board_time(int((t0 + ev.at_s) * 1e6))
            self.emit(Event("scripted", t0 + ev.at_s, ev.text))

    def emit(self, event: Event) -> str:
        """Handle ``event`` as the policy says; returns the action taken ("ignore" | "note" | "interrupt")."""
        action = self.policy.action(event.kind)
        shell = self._shell()
        running = shell is not None and shell.running
        if event.kind == "fall" and running and shell is not None:
            shell.interrupt([c for c in shell.registry.channels() if c in self._motion])
        if action == "ignore":
            return action
        self.events.append(event)
        self._turn.append(event)
        log.info("event: %s (%s)", event, action)
        if action == "interrupt" and running and shell is not None:
            if self._interrupted_by is None:
                self._interrupted_by = event
            shell.interrupt()
        for cb in list(self.on_event):
            cb(event, action)
        return action

    def end_turn(self) -> tuple[list[Event], Event | None]:
        """The events since the last turn ended and the one that interrupted it (None); starts afresh."""
        events, self._turn = self._turn, []
        by, self._interrupted_by = self._interrupted_by, None
        return events, by
