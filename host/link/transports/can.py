"""The host's CAN transport: protocol v1 over a python-can bus (SocketCAN, SLCAN, virtual, ...).

``open_can_transport(spec, log_path=...)`` -> :class:`CanLinkTransport`. On :meth:`connect` it
opens ``can.Bus(**spec.bus_kwargs())`` (python-can's own configuration, env vars and ``can.rc``,
fills in the interface/channel the spec leaves empty) with a filter on the board's node id, and
frames reach the asyncio loop through ``loop.add_reader`` on the bus's fd where it has one
(SocketCAN, SLCAN: every ready frame is drained with ``bus.recv(0)`` per wake-up), else through
python-can's ``can.Notifier`` thread (the virtual bus), handed over with ``call_soon_threadsafe``. For ``slcan`` the 2 s ``sleep_after_open``
python-can waits for real adapters defaults to 0 (a spec option overrides it). Given a callable
``resolve`` (as the serial transport takes a callable port), every :meth:`connect` re-resolves the
spec: a SLCAN board that came back on another pty is found again (its node id and FD mode must
stay the same).

Messages become frames and frames messages in the CAN wire engine shared with the board
(:class:`protocol.can.engine.CanEngine`: fixed layouts, the rest over ISO-TP with can-isotp), in the
robot's layout table (:func:`protocol.can.layouts.can_layouts` for ``servo_count``; :meth:`set_servo_count`).
This module only moves the engine's frames to and from python-can. Sending never blocks: frames queue
and are written in order; a refused write (SocketCAN's ENOBUFS on a full tx queue, python-can
issue #2004) keeps the frame at the head and retries after 1 ms doubling to 20 ms
(``tx_retries``); more than ``MAX_TX_FRAMES`` waiting raises ``LinkError`` (the bus is not
draining). On SLCAN the lines go out through :class:`~host.link.transports.slcan_tx.SlcanWriter`
instead of python-can's ``send`` (which spins in pyserial's write on a full port, freezing the
event loop, and loses the rest of a line the port took in part): at most ``SLCAN_CHUNK`` bytes
of whole lines are handed to the port at a time, the loop's writer callback (``add_writer``)
continues when the port has room again (``tx_retries`` counts the waits); SLCAN is read through
:class:`~host.link.transports.slcan_rx.BufferedSlcanBus`. Every frame both ways goes to the frame log
chosen by suffix (:func:`protocol.logfile.open_frame_log`: python-can's writers, ``.log`` candump,
``.asc``, ``.blf`` ...; wall-clock timestamps, the driver's for received frames; the direction is
the one this end knows, not python-can's ``is_rx``, which marks SocketCAN's vcan loop-back as sent;
received and sent frames carry the same channel, the bus's python-can channel, e.g. the SLCAN
adapter's tty, as the board's own log names it). :meth:`close` closes the frame log only once the
bus has been quiet for ``LINGER_QUIET_S`` (at most ``LINGER_MAX_S``): frames the board sends in answer
to the host's last ones (a lockstep board's last telemetry, an ISO-TP transfer under way) are logged,
so both ends' logs end with the same frames (issue 17 item 7); they are logged only, not decoded.

asyncio stays here (the reader and writer callbacks, ``call_later`` for the ISO-TP tick and the tx
retry, ``call_soon_threadsafe`` from python-can's Notifier thread), as in every transport adapter:
see :mod:`host.link.transports` for why. Opening the bus is :func:`anyio.to_thread.run_sync`.
"""

from __future__ import annotations

import asyncio
import errno
import logging
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import anyio
import anyio.to_thread
import can

from host.link.errors import LinkConfigError, LinkDown, LinkError
from host.link.transports.base import LossHandler, ReceiveHandler, Transport
from host.link.transports.slcan_tx import SlcanWriter
from protocol.can.bus_errors import describe_bus_open_error
from protocol.can.engine import CanEngine
from protocol.can.frame import CanFrame
from protocol.can.layouts import CanLayouts, can_layouts
from protocol.can.pycan import from_can_message, to_can_message
from protocol.can.slcan import format_frame
from protocol.codec import PayloadError
from protocol.linkkinds import link_kind
from protocol.linkspec import LinkSpec, LinkSpecError, parse_link_spec
from protocol.logfile import FrameLogWriter, open_frame_log
from protocol.messages import Message

__all__ = ["MAX_TX_FRAMES", "CanLinkTransport", "open_can_transport"]

MAX_TX_FRAMES = 4096
BACKOFF_MIN_S = 0.001
BACKOFF_MAX_S = 0.02
ISOTP_TICK_S = 0.002
FRAME_COST = 16
SLCAN_CHUNK = 1024  # bytes of SLCAN lines handed to the port at a time (the rest waits as frames)
LINGER_QUIET_S = 0.05  # close: the bus counts as drained after this long without a frame for this node
LINGER_MAX_S = 0.5  # close: at most this long (a realtime board reports until it is stopped)
log = logging.getLogger(__name__)

def _make_bus(kw: dict[str, Any]) -> can.BusABC:
    """``can.Bus(**kw)``, except that a SLCAN bus (named, or from python-can's configuration) is a
    :class:`~host.link.transports.slcan_rx.BufferedSlcanBus` (python-can 4.6.1 reads SLCAN one byte
    per system call); the configuration is resolved as ``can.Bus`` resolves it."""
    cfg = can.util.load_config(config=dict(kw))
    if cfg.get("interface") != "slcan":
        return can.Bus(**kw)  # type: ignore[arg-type]
    from host.link.transports.slcan_rx import BufferedSlcanBus

    del cfg["interface"]
    channel = cfg.pop("channel", None)
    # as can.Bus does: without a channel the class is called without one (and says what is missing)
    bus: can.BusABC = BufferedSlcanBus(**cfg) if channel is None else BufferedSlcanBus(channel, **cfg)
    return bus


class _Collect(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


def _open_bus(spec: LinkSpec, kw: dict[str, Any]) -> can.BusABC:
    """``can.Bus(**kw)``; any failure becomes one :class:`LinkConfigError` line (the driver's error is the cause).

    python-can's log records of the attempt (e.g. an interface module's import-time warnings) are held
    back: on failure the one line says what happened, on success they are logged under this module.
    """
    held = _Collect()
    root = logging.getLogger("can")
    root.addHandler(held)
    saved, root.propagate = root.propagate, False
    try:
        bus = _make_bus(kw)
    except Exception as e:  # python-can's interface classes raise all sorts (CanError, OSError, ValueError, struct.error...)
        raise LinkConfigError(describe_bus_open_error(spec, e, interfaces=can.VALID_INTERFACES)) from e
    finally:
        root.removeHandler(held)
        root.propagate = saved
    for r in held.records:
        log.log(r.levelno, "python-can: %s", r.getMessage())
    return bus


def _log_channel(spec: LinkSpec, bus: can.BusABC) -> str:
    """The channel named in the frame log, both directions: the bus's python-can channel (``vcan0``, the SLCAN
    adapter's tty, ``bus0``), python-can's configured one when the spec leaves it empty, else ``can0``."""
    if spec.channel:
        return spec.channel
    configured = getattr(bus, "channel", None)
    if isinstance(configured, str) and configured:
        return configured
    try:
        channel = can.util.load_config(config={"interface": spec.interface} if spec.interface else {}).get("channel")
    except Exception:  # no configuration at all: the log still needs a name
        channel = None
    return str(channel) if channel else "can0"


class _Listener(can.Listener):
    """Hands every received message (or the bus error) to the loop thread."""

    def __init__(self, loop: asyncio.AbstractEventLoop, owner: CanLinkTransport, generation: int) -> None:
        self.loop, self.owner, self.generation = loop, owner, generation

    def on_message_received(self, msg: can.Message) -> None:
        # through the owner's inbox, in order: what the loop has not taken when the transport closes
        # still reaches the frame log
        self.owner._inbox.append((msg, self.generation))
        try:
            self.loop.call_soon_threadsafe(self.owner._from_inbox)
        except RuntimeError:  # loop closed
            pass

    def on_error(self, exc: Exception) -> None:
        try:
            self.loop.call_soon_threadsafe(self.owner._lose, f"CAN receive failed: {exc}", self.generation)
        except RuntimeError:
            pass


class CanLinkTransport(Transport):
    """Protocol v1 over CAN to board ``spec.node`` (see the module docstring); ``servo_count`` is the
    robot's (None: not known yet, the default layout table until CAPS says)."""

    def __init__(self, spec: LinkSpec, *, log_path: str | Path | None = None, bus: can.BusABC | None = None,
                 resolve: Callable[[], LinkSpec | str] | None = None, servo_count: int | None = None) -> None:
        self.spec = spec
        self.layouts: CanLayouts = can_layouts() if servo_count is None else can_layouts(servo_count)
        self._resolve = resolve
        self.node = spec.node
        self.fd = spec.fd
        self._given_bus = bus
        self.bus: can.BusABC | None = None
        self._notifier: can.Notifier | None = None
        self._reader_fd: int | None = None
        self._slcan: SlcanWriter | None = None  # SLCAN: our own non-blocking line output
        self._writer_fd: int | None = None  # the fd the loop watches for room (SLCAN)
        self._generation = 0
        self._on_receive: ReceiveHandler | None = None
        self._on_lost: LossHandler | None = None
        self._txq: deque[CanFrame] = deque()
        self._inbox: deque[tuple[can.Message, int]] = deque()  # from python-can's Notifier thread
        self._retry: asyncio.TimerHandle | None = None
        self._tick: asyncio.TimerHandle | None = None
        self._backoff = BACKOFF_MIN_S
        self.tx_retries = 0
        self.tx_frames = 0
        self.rx_frames = 0
        self.error_frames = 0
        self.engine = CanEngine(self.node, "host", self.fd, self._txq.append, self.layouts)
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
        return FRAME_COST * len(self._txq) + (len(self._slcan.pending) if self._slcan is not None else 0)

    async def connect(self, on_receive: ReceiveHandler, on_lost: LossHandler) -> None:
        self.disconnect()
        loop = asyncio.get_running_loop()
        self._on_receive, self._on_lost = on_receive, on_lost
        if self._resolve is not None:
            self.spec = self._resolved()
        if self._given_bus is not None:
            bus = self._given_bus
        else:
            kw = self.spec.bus_kwargs()
            kw.setdefault("can_filters", [{"can_id": self.node, "can_mask": 0x7F, "extended": False}])
            if kw.get("interface") == "slcan":
                kw.setdefault("sleep_after_open", 0)
            # a worker thread (an SLCAN open may block on its port); abandoned when cancelled, as Ctrl-C must not wait
            bus = await anyio.to_thread.run_sync(_open_bus, self.spec, kw, abandon_on_cancel=True)
        self.bus = bus
        self._channel_name = _log_channel(self.spec, bus)
        if self.framelog is not None:
            self.framelog.channel = self._channel_name  # type: ignore[attr-defined]
        self._generation += 1
        self.engine.reset()
        self._txq.clear()
        self._reader_fd = None
        try:
            fd = int(bus.fileno())
        except (NotImplementedError, OSError, AttributeError, ValueError, TypeError):
            fd = -1
        from can.interfaces.slcan import slcanBus

        self._slcan = SlcanWriter(fd) if isinstance(bus, slcanBus) and fd >= 0 else None
        if fd >= 0:
            # the loop watches the bus's fd and drains every frame that is ready (python-can's Notifier
            # would take one frame per readiness callback, too slow for a lockstep board's bursts)
            loop.add_reader(fd, self._drain, self._generation)
            self._reader_fd = fd
        else:  # no fd (e.g. the virtual bus): python-can's Notifier reads in its thread
            # no loop= here: python-can would queue each message on the loop itself, out of close()'s reach;
            # the listener runs in the Notifier's thread and hands over through the inbox
            self._notifier = can.Notifier(bus, [_Listener(loop, self, self._generation)], timeout=0.05)

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

    def _drain(self, generation: int) -> None:
        bus = self.bus
        buffered = getattr(bus, "has_buffered_line", None)  # BufferedSlcanBus: lines read, not yet parsed
        for _ in range(1024):
            if bus is None or generation != self._generation:
                return
            try:
                msg = bus.recv(timeout=0)
            except (can.CanError, OSError, ValueError) as e:
                self._lose(f"CAN receive failed: {e}", generation)
                return
            if msg is None:
                if buffered is not None and buffered():
                    continue  # an adapter response or a filtered frame: more lines wait behind it
                return
            self._on_can(msg, generation)
        if buffered is not None and buffered():  # the fd will not wake us for lines already read
            asyncio.get_running_loop().call_soon(self._drain, generation)

    # --- receiving ------------------------------------------------------------------------

    def _from_inbox(self) -> None:
        try:
            msg, generation = self._inbox.popleft()
        except IndexError:  # taken by close()
            return
        self._on_can(msg, generation)

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
        if self.engine.busy or self._txq:
            self._pump()
            self._arm_tick()
        if items and self._on_receive is not None:
            self._on_receive(items)

    def _arm_tick(self) -> None:
        if self._tick is None and self.engine.busy and self.bus is not None:
            self._tick = asyncio.get_running_loop().call_later(ISOTP_TICK_S, self._on_tick)

    def _on_tick(self) -> None:
        self._tick = None
        items = self.engine.poll()
        self._pump()
        self._arm_tick()
        if items and self._on_receive is not None:
            self._on_receive(items)

    # --- sending --------------------------------------------------------------------------

    def send(self, msg: Message, seq: int) -> None:
        if self.bus is None:
            raise LinkDown(f"CAN link {self.spec} is not connected")
        if len(self._txq) >= MAX_TX_FRAMES:
            raise LinkError(f"CAN transmit queue over {MAX_TX_FRAMES} frames: the bus is not draining")
        try:
            fixed = self.engine.is_fixed(msg)
            self.engine.send(msg, seq)
            if not fixed:
                items = self.engine.poll()
                self._pump()
                self._arm_tick()
                if items and self._on_receive is not None:
                    self._on_receive(items)
        except PayloadError as e:
            raise LinkError(f"cannot send {type(msg).__name__} on CAN: {e}") from None
        except BufferError as e:
            raise LinkError(str(e)) from None
        self._pump()

    def _log_sent(self, frame: CanFrame) -> None:
        if self.framelog is not None:
            self.framelog.write_can("tx", frame)

    def _pump(self) -> None:
        bus = self.bus
        if bus is None or self._retry is not None:
            return
        if self._slcan is not None:
            self._pump_slcan(self._slcan)
            return
        while self._txq:
            frame = self._txq[0]
            try:
                bus.send(to_can_message(frame), timeout=0.0)
            except can.CanOperationError as e:
                # ENOBUFS (python-can #2004) or a full serial port: keep it, retry with backoff
                self.tx_retries += 1
                code = getattr(e, "error_code", None)
                if code not in (None, errno.ENOBUFS, errno.EAGAIN) and code in (errno.ENODEV, errno.ENXIO, errno.ENETDOWN):
                    self._lose(f"CAN send failed: {e}", self._generation)
                    return
                self._retry = asyncio.get_running_loop().call_later(self._backoff, self._retry_now)
                self._backoff = min(self._backoff * 2, BACKOFF_MAX_S)
                return
            except can.CanError as e:
                self._lose(f"CAN send failed: {e}", self._generation)
                return
            self._txq.popleft()
            self.tx_frames += 1
            self._backoff = BACKOFF_MIN_S
            self._log_sent(frame)

    def _retry_now(self) -> None:
        self._retry = None
        self._pump()

    def _pump_slcan(self, out: SlcanWriter) -> None:
        """Whole SLCAN lines to the port as far as it takes them; the rest waits for the loop's
        writer callback (never blocks, never splits a line)."""
        while True:
            try:
                done = out.write()
            except OSError as e:
                self._lose(f"CAN send failed: SLCAN port write: {e}", self._generation)
                return
            if not done:
                self.tx_retries += 1
                self._wait_writable(out.fd)
                return
            if not self._txq:
                self._stop_waiting_writable()
                return
            while self._txq and len(out.pending) < SLCAN_CHUNK:
                frame = self._txq.popleft()
                out.push(format_frame(frame))
                self.tx_frames += 1
                self._log_sent(frame)

    def _wait_writable(self, fd: int) -> None:
        if self._writer_fd is None:
            asyncio.get_running_loop().add_writer(fd, self._on_writable, self._generation)
            self._writer_fd = fd

    def _stop_waiting_writable(self) -> None:
        if self._writer_fd is not None:
            try:
                asyncio.get_running_loop().remove_writer(self._writer_fd)
            except (RuntimeError, ValueError, OSError):
                pass
            self._writer_fd = None

    def _on_writable(self, generation: int) -> None:
        if generation == self._generation:
            self._pump()

    # --- closing --------------------------------------------------------------------------

    def _lose(self, reason: str, generation: int) -> None:
        if generation != self._generation or self.bus is None:
            return
        self.disconnect()
        if self._on_lost is not None:
            self._on_lost(reason)

    def _stop_reading(self) -> None:
        """No more frames to the loop (the bus stays open)."""
        if self._reader_fd is not None:
            try:
                asyncio.get_running_loop().remove_reader(self._reader_fd)
            except (RuntimeError, ValueError, OSError):
                pass
            self._reader_fd = None
        if self._notifier is not None:
            try:
                self._notifier.stop(timeout=0.2)
            except Exception:
                pass
            self._notifier = None

    def disconnect(self) -> None:
        self._generation += 1
        for h in (self._retry, self._tick):
            if h is not None:
                h.cancel()
        self._retry = self._tick = None
        self._stop_reading()
        self._stop_waiting_writable()
        self._slcan = None
        self._inbox.clear()
        if self.bus is not None and self.bus is not self._given_bus:
            _shutdown(self.bus)
        self.bus = None

    def _linger(self, bus: can.BusABC, log: FrameLogWriter) -> None:
        """Log what the loop has not taken yet, then every frame until the bus is quiet (see the module
        docstring); python-can's errors end it."""
        generation = self._generation
        while self._inbox:
            msg, gen = self._inbox.popleft()
            if gen == generation and not msg.is_error_frame:
                log.write_can("rx", from_can_message(msg), msg.timestamp or None)
        deadline = time.monotonic() + LINGER_MAX_S
        while (left := deadline - time.monotonic()) > 0:
            try:
                got = bus.recv(timeout=min(LINGER_QUIET_S, left))
            except (can.CanError, OSError, ValueError):
                return
            if got is None:
                return
            if not got.is_error_frame:
                log.write_can("rx", from_can_message(got), got.timestamp or None)

    def close(self) -> None:
        if self.bus is not None and self.framelog is not None:
            self._stop_reading()
            self._linger(self.bus, self.framelog)
        self.disconnect()
        if self.framelog is not None:
            self.framelog.close()
            self.framelog = None


def _shutdown(bus: can.BusABC) -> None:
    """``bus.shutdown()``, bounded: python-can's slcan bus writes ``C`` (close the channel) first,
    a blocking write by default, which would hang on a port the other end no longer reads; its
    pyserial port (``serialPortOrig``) gets a 50 ms write timeout, and is closed even if the
    ``C`` did not go out."""
    port = getattr(bus, "serialPortOrig", None)
    if port is not None:
        try:
            port.write_timeout = 0.05
        except Exception:
            pass
    try:
        bus.shutdown()
    except Exception:
        if port is not None:
            try:
                port.close()
            except Exception:
                pass


def open_bus(spec: LinkSpec) -> can.BusABC:
    """Open the python-can bus ``spec`` names (the caller shuts it down); :class:`LinkConfigError` with one
    line when python-can cannot (e.g. to check a SocketCAN interface before anything starts)."""
    return _open_bus(spec, spec.bus_kwargs())


def open_can_transport(spec: LinkSpec, *, log_path: str | Path | None = None, **options: Any) -> CanLinkTransport:
    """The host's CAN transport for ``spec`` (``bus=`` may pass an already open python-can bus,
    ``resolve=`` a callable that gives the spec anew on every connect, ``servo_count=`` the robot's)."""
    return CanLinkTransport(spec, log_path=log_path, bus=options.get("bus"), resolve=options.get("resolve"),
                            servo_count=options.get("servo_count"))
