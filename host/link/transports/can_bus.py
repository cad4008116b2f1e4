"""Opening and closing the python-can bus under the host's CAN transport, and its last frames for the log.

Part of :class:`host.link.transports.can.CanLinkTransport` (python-can's ``Bus`` side of its Bus /
Notifier / Listener split; the receive hand-over is :mod:`host.link.transports.can_rx`, the send
pump :mod:`host.link.transports.can_tx`):

* :func:`open_link_bus` opens ``can.Bus(**spec.bus_kwargs())`` for the link (python-can's own
  configuration, env vars and ``can.rc``, fills in the interface/channel the spec leaves empty) with a
  filter on the board's node id; for ``slcan`` the 2 s ``sleep_after_open`` python-can waits for real
  adapters defaults to 0 (a spec option overrides it), and the bus is a
  :class:`~host.link.transports.slcan_rx.BufferedSlcanBus` (python-can 4.6.1 reads SLCAN one byte per
  system call). The open runs in a worker thread (:func:`anyio.to_thread.run_sync`: a SLCAN open may
  block on its port), abandoned when cancelled, as Ctrl-C must not wait. Any failure is one
  :class:`~host.link.errors.LinkConfigError` line (:func:`protocol.can.bus_errors.describe_bus_open_error`);
  python-can's log records of the attempt are held back and, on success, logged under the CAN
  transport's logger. :func:`open_bus` is the same open for a spec as given (a preflight check).
* :func:`log_channel` names the channel both directions of the frame log carry (the bus's python-can
  channel, e.g. the SLCAN adapter's tty, as the board's own log names it).
* :func:`shutdown_bus` closes a bus without hanging on a port the other end no longer reads.
* :func:`log_until_quiet` is the close-time linger: the frame log is closed only once the bus has been
  quiet for ``LINGER_QUIET_S`` (at most ``LINGER_MAX_S``), so frames the board sends in answer to the
  host's last ones (a lockstep board's last telemetry, an ISO-TP transfer under way) are logged and
  both ends' logs end with the same frames (issue 17 item 7); they are logged only, not decoded.

No event loop here: these calls block (the open in a worker thread; the linger blocks ``close()`` for
at most ``LINGER_MAX_S``, by design, after the loop's reader is gone).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterable
from typing import Any

import anyio
import anyio.to_thread
import can

from host.link.errors import LinkConfigError
from protocol.can.bus_errors import describe_bus_open_error
from protocol.can.pycan import from_can_message
from protocol.linkspec import LinkSpec
from protocol.logfile import FrameLogWriter

__all__ = ["LINGER_MAX_S", "LINGER_QUIET_S", "bus_fd", "log_channel", "log_until_quiet", "open_bus",
           "open_link_bus", "shutdown_bus"]

LINGER_QUIET_S = 0.05  # close: the bus counts as drained after this long without a frame for this node
LINGER_MAX_S = 0.5  # close: at most this long (a realtime board reports until it is stopped)
# the CAN transport's logger (python-can's held-back records are the transport's to report)
log = logging.getLogger("host.link.transports.can")


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
    back: on failure the one line says what happened, on success they are logged under the CAN transport.
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


def open_bus(spec: LinkSpec) -> can.BusABC:
    """Open the python-can bus ``spec`` names (the caller shuts it down); :class:`LinkConfigError` with one
    line when python-can cannot (e.g. to check a SocketCAN interface before anything starts)."""
    return _open_bus(spec, spec.bus_kwargs())


async def open_link_bus(spec: LinkSpec, node: int) -> can.BusABC:
    """The bus for the link to board ``node``: ``spec``'s bus with a filter on ``node`` (unless the spec
    names filters) and, on SLCAN, no ``sleep_after_open`` (unless the spec names one); opened in a
    worker thread. Raises :class:`LinkConfigError` (see :func:`open_bus`)."""
    kw = spec.bus_kwargs()
    kw.setdefault("can_filters", [{"can_id": node, "can_mask": 0x7F, "extended": False}])
    if kw.get("interface") == "slcan":
        kw.setdefault("sleep_after_open", 0)
    # a worker thread (an SLCAN open may block on its port); abandoned when cancelled, as Ctrl-C must not wait
    return await anyio.to_thread.run_sync(_open_bus, spec, kw, abandon_on_cancel=True)


def bus_fd(bus: can.BusABC) -> int:
    """The bus's file descriptor for the loop to watch (``bus.fileno()``), -1 when it has none (the virtual bus)."""
    try:
        return int(bus.fileno())
    except (NotImplementedError, OSError, AttributeError, ValueError, TypeError):
        return -1


def log_channel(spec: LinkSpec, bus: can.BusABC) -> str:
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


def log_until_quiet(bus: can.BusABC, framelog: FrameLogWriter, pending: Iterable[can.Message]) -> None:
    """Log ``pending`` (received, not yet taken by the loop), then every frame ``bus`` receives until it has
    been quiet for :data:`LINGER_QUIET_S`, at most :data:`LINGER_MAX_S`; all as ``rx``, error frames
    skipped. python-can's errors end it. Blocks (the loop no longer reads the bus)."""
    for msg in pending:
        if not msg.is_error_frame:
            framelog.write_can("rx", from_can_message(msg), msg.timestamp or None)
    deadline = time.monotonic() + LINGER_MAX_S
    while (left := deadline - time.monotonic()) > 0:
        try:
            got = bus.recv(timeout=min(LINGER_QUIET_S, left))
        except (can.CanError, OSError, ValueError):
            return
        if got is None:
            return
        if not got.is_error_frame:
            framelog.write_can("rx", from_can_message(got), got.timestamp or None)


def shutdown_bus(bus: can.BusABC) -> None:
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
