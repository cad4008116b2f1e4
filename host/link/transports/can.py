"""The host's CAN transport: protocol v1 over a python-can bus (SocketCAN, SLCAN, virtual, ...).

``open_can_transport(spec, log_path=...)`` -> :class:`CanLinkTransport`, the
:class:`~host.link.transports.base.Transport` for CAN links. It is the facade over three parts, split
along their jobs as python-can splits ``Bus`` / ``Notifier`` / ``Listener``:

* :mod:`host.link.transports.can_bus`: opening the python-can bus on :meth:`~CanLinkTransport.connect`
  (``can.Bus(**spec.bus_kwargs())`` with a filter on the board's node id, in a worker thread; one
  :class:`~host.link.errors.LinkConfigError` line when it cannot), the frame log's channel name, the
  bounded shutdown, and the linger on :meth:`~CanLinkTransport.close` (the frame log is closed once the
  bus has been quiet ``LINGER_QUIET_S``, at most ``LINGER_MAX_S``, so both ends' logs end with the same
  frames);
* :mod:`host.link.transports.can_rx`: received frames to the loop (``loop.add_reader`` on the bus's fd,
  or python-can's Notifier thread handing over through an inbox), tagged with the connection generation;
* :mod:`host.link.transports.can_tx`: the send pump (never blocks: frames queue and are written in
  order; ENOBUFS backoff; SLCAN lines through :class:`~host.link.transports.slcan_tx.SlcanWriter` with
  ``add_writer`` back-pressure); more than ``MAX_TX_FRAMES`` waiting raises ``LinkError``.

What stays here: the connection life cycle (the generation, incremented on every connect and
disconnect, that makes callbacks of an earlier connection no-ops), the CAN wire engine shared with the
board (:class:`protocol.can.engine.CanEngine`: fixed layouts, the rest over ISO-TP with can-isotp) in
the robot's layout table (:func:`protocol.can.layouts.can_layouts` for ``servo_count``;
:meth:`~CanLinkTransport.set_servo_count`), its ISO-TP tick, and the frame log. Given a callable
``resolve`` (as the serial transport takes a callable port), every :meth:`~CanLinkTransport.connect`
re-resolves the spec: a SLCAN board that came back on another pty is found again (its node id and FD
mode must stay the same). Every frame both ways goes to the frame log chosen by suffix
(:func:`protocol.logfile.open_frame_log`: python-can's writers, ``.log`` candump, ``.asc``, ``.blf``
...; wall-clock timestamps, the driver's for received frames; the direction is the one this end knows,
not python-can's ``is_rx``, which marks SocketCAN's vcan loop-back as sent; received and sent frames
carry the same channel, the bus's python-can channel, e.g. the SLCAN adapter's tty, as the board's own
log names it).

asyncio stays at this layer (the reader and writer callbacks, ``call_later`` for the ISO-TP tick and
the tx retry, ``call_soon_threadsafe`` from python-can's Notifier thread), as in every transport
adapter: see :mod:`host.link.transports` for why. Opening the bus is :func:`anyio.to_thread.run_sync`.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can

from host.link.errors import LinkDown, LinkError
from host.link.transports.base import LossHandler, ReceiveHandler, Transport
from host.link.transports.can_bus import (LINGER_MAX_S, LINGER_QUIET_S, bus_fd, log_channel, log_until_quiet,
                                          open_bus, open_link_bus, shutdown_bus)
from host.link.transports.can_rx import CanReceiver
from host.link.transports.can_tx import MAX_TX_FRAMES, CanSender
from protocol.can.engine import CanEngine
from protocol.can.frame import CanFrame
from protocol.can.layouts import CanLayouts, can_layouts
from protocol.can.pycan import from_can_message
from protocol.codec import PayloadError
from protocol.linkkinds import link_kind
from protocol.linkspec import LinkSpec, LinkSpecError, parse_link_spec
from protocol.logfile import FrameLogWriter, open_frame_log
from protocol.messages import Message

__all__ = ["LINGER_MAX_S", "LINGER_QUIET_S", "MAX_TX_FRAMES", "CanLinkTransport", "open_bus", "open_can_transport"]

ISOTP_TICK_S = 0.002  # while an ISO-TP transfer is under way, poll the engine this often


class CanLinkTransport(Transport):
    """Protocol v1 over CAN to board ``spec.node`` (see the module docstring); ``servo_count`` is the
    robot's (None: not known yet, the default layout table until CAPS says). Counters: ``tx_frames``,
    ``tx_retries`` (the send pump's), ``rx_frames``, ``error_frames``."""

    def __init__(self, spec: LinkSpec, *, log_path: str | Path | None = None, bus: can.BusABC | None = None,
                 resolve: Callable[[], LinkSpec | str] | None = None, servo_count: int | None = None) -> None:
        self.spec = spec
        self.layouts: CanLayouts = can_layouts() if servo_count is None else can_layouts(servo_count)
        self._resolve = resolve
        self.node = spec.node
        self.fd = spec.fd
        self._given_bus = bus
        self.bus: can.BusABC | None = None
        self._generation = 0
        self._on_receive: ReceiveHandler | None = None
        self._on_lost: LossHandler | None = None
        self._rx = CanReceiver(self._on_can, self._lose, self._is_current)
        self._tx = CanSender(self._log_sent, self._lose)
        self._tick: asyncio.TimerHandle | None = None
        self.rx_frames = 0
        self.error_frames = 0
        self.engine = CanEngine(self.node, "host", self.fd, self._tx.queue.append, self.layouts)
        self.framelog: FrameLogWriter | None = (
            open_frame_log(log_path, "can", channel=spec.channel or "can0") if log_path else None)
        self._channel_name = spec.channel or "can0"

    @property
    def decoder(self) -> Any:
        """The engine's fixed-layout reassembler (its ``errors``, ``error_count`` counters)."""
        return self.engine.decoder

    @property
    def isotp(self) -> Any:
        """The engine's ISO-TP link."""
        return self.engine.isotp

    @property
    def tx_retries(self) -> int:
        """Writes the bus refused (and retried) or SLCAN waits for room on the port."""
        return self._tx.tx_retries

    @property
    def tx_frames(self) -> int:
        """Frames handed to the bus (or to the SLCAN port)."""
        return self._tx.tx_frames

    @property
    def name(self) -> str:
        return f"{self.spec} (node {self.node})"

    @property
    def link_spec(self) -> str:
        return str(self.spec)  # the node id is in the spec (?node=N) when it is not the default

    def set_servo_count(self, servo_count: int) -> None:
        self.layouts = can_layouts(servo_count)
        self.engine.set_layouts(self.layouts)

    @property
    def connected(self) -> bool:
        return self.bus is not None

    @property
    def backlog(self) -> int:
        return self._tx.backlog

    async def connect(self, on_receive: ReceiveHandler, on_lost: LossHandler) -> None:
        self.disconnect()
        loop = asyncio.get_running_loop()
        self._on_receive, self._on_lost = on_receive, on_lost
        if self._resolve is not None:
            self.spec = self._resolved()
        bus = self._given_bus if self._given_bus is not None else await open_link_bus(self.spec, self.node)
        self.bus = bus
        self._channel_name = log_channel(self.spec, bus)
        if self.framelog is not None:
            self.framelog.channel = self._channel_name  # type: ignore[attr-defined]
        self._generation += 1
        self.engine.reset()
        fd = bus_fd(bus)
        self._tx.attach(bus, fd, self._generation)
        self._rx.start(loop, bus, fd, self._generation)

    def _resolved(self) -> LinkSpec:
        assert self._resolve is not None
        try:
            spec = parse_link_spec(self._resolve())
        except (LinkSpecError, OSError) as e:
            raise LinkDown(f"cannot resolve the CAN link: {e}") from None
        if link_kind(spec).wire != "can" or spec.node != self.node or spec.fd != self.fd:
            raise LinkDown(f"the link now resolves to {spec}, not a CAN link to node {self.node} "
                           f"({'FD' if self.fd else 'classic'}) as before")
        return spec

    def _is_current(self, generation: int) -> bool:
        return generation == self._generation

    def use_board_clock(self, board_clock: Callable[[], int] | None) -> None:
        self.engine.use_board_clock(board_clock)

    # --- receiving ------------------------------------------------------------------------

    def _on_can(self, msg: can.Message, generation: int) -> None:
        if generation != self._generation or self.bus is None:
            return
        self.rx_frames += 1
        if msg.is_error_frame:
            self.error_frames += 1
            return
        frame = from_can_message(msg)
        if self.framelog is not None:  # "rx" as this end knows it (python-can marks vcan loop-back as sent)
            self.framelog.write_can("rx", frame, msg.timestamp or None)
        items = self.engine.feed(frame)
        if self.engine.busy or self._tx.queue:
            self._tx.pump()
            self._arm_tick()
        if items and self._on_receive is not None:
            self._on_receive(items)

    def _arm_tick(self) -> None:
        if self._tick is None and self.engine.busy and self.bus is not None:
            self._tick = asyncio.get_running_loop().call_later(ISOTP_TICK_S, self._on_tick)

    def _on_tick(self) -> None:
        self._tick = None
        items = self.engine.poll()
        self._tx.pump()
        self._arm_tick()
        if items and self._on_receive is not None:
            self._on_receive(items)

    # --- sending --------------------------------------------------------------------------

    def send(self, msg: Message, seq: int) -> int:
        if self.bus is None:
            raise LinkDown(f"CAN link {self.spec} is not connected")
        if len(self._tx.queue) >= MAX_TX_FRAMES:
            raise LinkError(f"CAN transmit queue over {MAX_TX_FRAMES} frames: the bus is not draining")
        try:
            fixed = self.engine.is_fixed(msg)
            self.engine.send(msg, seq)
            if not fixed:
                items = self.engine.poll()
                self._tx.pump()
                self._arm_tick()
                if items and self._on_receive is not None:
                    self._on_receive(items)
        except PayloadError as e:
            raise LinkError(f"cannot send {type(msg).__name__} on CAN: {e}") from None
        except BufferError as e:
            raise LinkError(str(e)) from None
        self._tx.pump()
        return 0

    def _log_sent(self, frame: CanFrame) -> None:
        if self.framelog is not None:
            self.framelog.write_can("tx", frame)

    # --- closing --------------------------------------------------------------------------

    def _lose(self, reason: str, generation: int) -> None:
        if generation != self._generation or self.bus is None:
            return
        self.disconnect()
        if self._on_lost is not None:
            self._on_lost(reason)

    def disconnect(self) -> None:
        self._generation += 1
        self._tx.cancel_retry()
        if self._tick is not None:
            self._tick.cancel()
        self._tick = None
        self._rx.stop()
        self._tx.detach()
        self._rx.clear()
        if self.bus is not None and self.bus is not self._given_bus:
            shutdown_bus(self.bus)
        self.bus = None

    def close(self) -> None:
        if self.bus is not None and self.framelog is not None:
            self._rx.stop()  # what the loop has not taken yet, then the bus until it is quiet, to the log
            log_until_quiet(self.bus, self.framelog, self._rx.leftovers(self._generation))
        self.disconnect()
        if self.framelog is not None:
            self.framelog.close()
            self.framelog = None


def open_can_transport(spec: LinkSpec, *, log_path: str | Path | None = None, **options: Any) -> CanLinkTransport:
    """The host's CAN transport for ``spec`` (``bus=`` may pass an already open python-can bus,
    ``resolve=`` a callable that gives the spec anew on every connect, ``servo_count=`` the robot's)."""
    return CanLinkTransport(spec, log_path=log_path, bus=options.get("bus"), resolve=options.get("resolve"),
                            servo_count=options.get("servo_count"))
