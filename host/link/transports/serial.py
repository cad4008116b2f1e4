"""The serial transport: protocol v1 over a pyserial port (COBS + CRC framing, JSON-Lines frame log).

:class:`SerialLinkTransport` is the :class:`host.link.transports.base.Transport` for
serial links; :class:`SerialPort` is the byte pipe under it, a pyserial port driven
by the asyncio loop.

Reading: where the port has a selectable file descriptor (POSIX serial ports and
ptys) the loop watches it with ``loop.add_reader`` and reads with
``serial.read(in_waiting or 1)`` at ``timeout=0`` (what pyserial-asyncio does on
POSIX); otherwise (Windows, some ``serial_for_url`` handlers) a daemon thread reads
with a short timeout and hands bytes to the loop with ``call_soon_threadsafe``
(pyserial's own answer in pyserial#37).

Writing: with a file descriptor the bytes go out with ``os.write`` on the
non-blocking fd, and what does not fit waits for ``loop.add_writer``. pyserial's
``write`` is not used there because with ``write_timeout=0`` it retries EAGAIN in a
busy loop and with any other timeout it blocks the event loop. The thread
transport writes with pyserial and a bounded ``write_timeout``.

A vanished port (pty master closed, USB unplugged) shows up as a read error; pyserial's
"readiness to read but returned no data" ``SerialException`` means, on a tty, that another
process read the bytes first (two hosts on one board: :data:`SHARED_PORT` says so). Either way
``on_lost(reason)`` is called once and the transport closes.

Opening: a device is opened exclusively (pyserial's ``exclusive``, an advisory ``flock``), so a
second GhostShell host on the same board cannot open it ("another host has it open"). A port that
cannot be opened on the first connection (no such device, not a tty, in use by another host, a
pyserial URL it cannot parse) is a :class:`~host.link.errors.LinkConfigError` (the port as given
cannot be used: exit status 2 in every command); after a connection, the same failure while
reconnecting is a vanished port (:class:`~host.link.errors.LinkDown`, retried).

The loop here is asyncio's (``add_reader``/``add_writer``, ``call_soon_threadsafe``), as in every
transport adapter; :mod:`host.link.transports` says why.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import os
import threading
import time
from collections.abc import Callable, Iterator

from pathlib import Path

import serial

from host.link.deferred import DeferredWork
from host.link.errors import LinkConfigError, LinkDown, LinkError
from host.link.transports.base import LossHandler, ReceiveHandler, Transport
from protocol.codec import WIRE_SCHEMA_16, WireSchema, schema_for
from protocol.framing import DecodeError, Frame, FrameDecoder, encode_frame
from protocol.logfile import FrameLogWriter, JsonlFrameLog, open_frame_log
from protocol.messages import Message

__all__ = ["MAX_TX_BACKLOG", "SerialLinkTransport", "SerialPort"]

_log = logging.getLogger("host.link")

MAX_TX_BACKLOG = 256 * 1024  # bytes waiting for the port before writes are refused

#: After a corked burst (a motion start's frame and FLUSH) is written, the writer sleeps this long (s;
#: the kernel rounds it up to the thread's timer slack, ~55 us by default): it blocks, so whatever the
#: write made runnable on this CPU runs first. A pty write only queues the hand-over to the reader
#: (the tty layer's flip-buffer work item, run by a kernel worker that the wake-up usually puts on the
#: writer's CPU); a writer that goes on computing (the start's frame-log records, its listeners, the
#: re-sent grid) held that worker, and the board, back for as long: at the board the start read
#: p50 0.10, p90 1.31, max 4.46 ms after the fastest message (bench_latency --repeat 4, 196 starts,
#: quiet); with this sleep p50 0.01, p90 1.01 and 0.42, max 3.84 and 3.43 ms (two such runs), and the
#: motion token -> servo p99 5.3 -> 4.7 and 4.5 ms (n = 136 each; docs/reference/benchmarks.md).
#: ``os.sched_yield`` did not help there: it need not give the CPU to a nice-0 worker.
BURST_HANDOFF_S = 1e-6


def _hand_over() -> None:
    """Block for :data:`BURST_HANDOFF_S`: the pty's hand-over of what was just written runs now."""
    time.sleep(BURST_HANDOFF_S)

_NO_DATA = "readiness to read but returned no data"  # pyserial's text for select-ready + an empty read


def SHARED_PORT(url: str) -> str:  # noqa: N802 - a message template, named like a constant
    """Why a read found nothing though the port was readable: another reader took the bytes."""
    return (f"another program is reading {url} at the same time (a second host on the same board?); "
            "a board serves one host at a time: stop the other host first")


def _read_failed(url: str, e: BaseException) -> str:
    return SHARED_PORT(url) if _NO_DATA in str(e) else f"read failed: {e}"


class SerialPort:
    """One open port; ``on_data(bytes)`` and ``on_lost(str)`` are called on the loop thread."""

    def __init__(
        self,
        url: str,
        baud: int,
        on_data: Callable[[bytes], None],
        on_lost: Callable[[str], None],
        *,
        force_thread: bool = False,
    ) -> None:
        self.url = url
        self._loop = asyncio.get_running_loop()
        self._on_data = on_data
        self._on_lost = on_lost
        self._closed = False
        self._tx = bytearray()
        self._corked = False
        self._thread: threading.Thread | None = None
        self._writer_added = False
        # a device is opened for this host alone (pyserial's exclusive: flock): a second host on the same
        # board is refused at once with a clear reason, instead of both hosts stealing each other's bytes
        exclusive = {"exclusive": True} if "://" not in url and os.name == "posix" else {}
        self.ser = serial.serial_for_url(url, baudrate=baud, timeout=0, write_timeout=0, **exclusive)
        fd: int | None = None
        if not force_thread:
            try:
                fd = self.ser.fileno()
            except Exception:
                fd = None
        self.fd = fd
        if fd is not None:
            self._loop.add_reader(fd, self._read_ready)
        else:
            self.ser.timeout = 0.05
            self.ser.write_timeout = 1.0
            self._thread = threading.Thread(target=self._reader_thread, name=f"serial-rx {url}", daemon=True)
            self._thread.start()

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def backlog(self) -> int:
        """Bytes accepted by :meth:`write` but not yet handed to the OS."""
        return len(self._tx)

    # --- reading ---------------------------------------------------------------------------

    def _read_ready(self) -> None:
        if self._closed:
            return
        try:
            data = self.ser.read(max(1, self.ser.in_waiting))
        except (serial.SerialException, OSError) as e:
            self._lose(_read_failed(self.url, e))
            return
        if data:
            self._on_data(bytes(data))

    def _reader_thread(self) -> None:
        try:
            while not self._closed:
                try:
                    data = self.ser.read(max(1, self.ser.in_waiting))
                except Exception as e:  # the port vanished
                    if not self._closed:
                        self._loop.call_soon_threadsafe(self._lose, _read_failed(self.url, e))
                    return
                if data:
                    self._loop.call_soon_threadsafe(self._deliver, bytes(data))
        except RuntimeError:  # the loop closed while a read was in progress (the port's close raced it)
            return

    def _deliver(self, data: bytes) -> None:
        if not self._closed:
            self._on_data(data)

    # --- writing ---------------------------------------------------------------------------

    def write(self, data: bytes) -> None:
        """Queue ``data`` for the port; raises ``BufferError`` if the port has stopped taking bytes."""
        if self._closed:
            raise ConnectionError("port is closed")
        if len(self._tx) + len(data) > MAX_TX_BACKLOG:
            raise BufferError(f"transmit backlog over {MAX_TX_BACKLOG} bytes: the board is not reading")
        if self.fd is None:
            try:
                self.ser.write(data)
            except (serial.SerialException, OSError) as e:
                self._lose(f"write failed: {e}")
                raise ConnectionError(str(e)) from None
            return
        self._tx += data
        if not self._corked:
            self._write_ready()

    @contextlib.contextmanager
    def corked(self) -> Iterator[None]:
        """Writes inside are queued and go out in one ``os.write`` when the block ends (TCP_CORK's idea),
        so the far end reads them together. A port without a file descriptor writes at once."""
        if self._corked or self.fd is None:
            yield
            return
        self._corked = True
        try:
            yield
        finally:
            self._corked = False
            wrote = bool(self._tx)
            self._write_ready()
            if wrote and not self._closed:
                _hand_over()

    def _write_ready(self) -> None:
        if self._closed or self.fd is None:
            return
        while self._tx:
            try:
                n = os.write(self.fd, self._tx)
            except BlockingIOError:
                break
            except InterruptedError:
                continue
            except OSError as e:
                self._lose(f"write failed: {e}")
                return
            del self._tx[:n]
        if self._tx and not self._writer_added:
            self._loop.add_writer(self.fd, self._write_ready)
            self._writer_added = True
        elif not self._tx and self._writer_added:
            self._loop.remove_writer(self.fd)
            self._writer_added = False

    # --- closing ---------------------------------------------------------------------------

    def _lose(self, reason: str) -> None:
        if self._closed:
            return
        self.close()
        self._on_lost(reason)

    def close(self) -> None:
        """Stop watching the port and close it (idempotent)."""
        if self._closed:
            return
        self._closed = True
        if self.fd is not None:
            try:
                self._loop.remove_reader(self.fd)
                if self._writer_added:
                    self._loop.remove_writer(self.fd)
            except Exception:
                pass
        try:
            self.ser.close()
        except Exception:
            pass


def open_failure(url: str, e: BaseException) -> str:
    """One line for a port that could not be opened as given (pyserial's error, rephrased where it is obscure)."""
    text = str(e)
    if "exclusively lock" in text:
        why = ("another host has it open (a second host on the same board?); a board serves one host at a time: "
               "stop the other host (ghostshell run, chat, mcp, pose, tour) first")
        return f"cannot open serial port {url!r}: {why}"
    if "Inappropriate ioctl" in text or getattr(e, "errno", None) == errno.ENOTTY:
        why = "it is not a serial port or tty (its terminal settings cannot be set)"
    elif isinstance(e, (TypeError, ValueError)) and "://" in url:
        why = f"pyserial cannot use this URL ({e})"
    elif "No such file" in text or getattr(e, "errno", None) == errno.ENOENT:
        why = "there is no such device"
    elif "Permission denied" in text or getattr(e, "errno", None) == errno.EACCES:
        why = "permission denied (is your user in the dialout group?)"
    else:
        why = text
    return (f"cannot open serial port {url!r}: {why}; give the port a running board announced (`ghostshell board "
            "--link pty` prints /dev/pts/N), a serial device such as /dev/ttyUSB0, a pyserial URL, or pty "
            "to start the emulated board")


def is_vanished_error(e: BaseException) -> bool:
    """True for errors meaning the device is gone rather than misconfigured."""
    return isinstance(e, OSError) and e.errno in (errno.ENOENT, errno.EIO, errno.ENXIO, errno.ENODEV)


class SerialLinkTransport(Transport):
    """Protocol v1 frames over one serial port / pty / pyserial URL (see the module docstring).

    ``baud`` is the port's rate (ignored by ptys); ``log_path`` gets one JSON-Lines record
    per frame both ways (:func:`protocol.logfile.open_frame_log`, ``t`` = host ``time.monotonic()``;
    a sent frame is logged as its wire bytes decode, as the board logs it; created with the first record);
    ``force_thread`` reads in a thread even where the port has a file descriptor. ``url`` may
    be a callable, resolved again on every :meth:`connect`. ``servo_count`` (the robot's; default
    none known: the u16 schema) picks the wire schema frames are encoded and decoded with.
    """

    def __init__(self, url: str | Callable[[], str], *, baud: int = 115200, log_path: str | Path | None = None,
                 force_thread: bool = False, servo_count: int | None = None) -> None:
        self._url = url
        self.url = url if isinstance(url, str) else ""
        self.baud = baud
        self.force_thread = force_thread
        self.schema: WireSchema = WIRE_SCHEMA_16 if servo_count is None else schema_for(servo_count)
        self.framelog: FrameLogWriter | None = (
            open_frame_log(log_path, "serial", schema=self.schema, lazy=True) if log_path else None)
        self._decoder = FrameDecoder(schema=self.schema)
        self._port: SerialPort | None = None
        self._on_receive: ReceiveHandler | None = None
        self._ever_connected = False
        self._log_held: list[bytes] | None = None  # sent inside burst(), not yet logged
        #: the frame log's records are written from the loop after the send or read that made them
        #: (decoding a sent frame and its JSON line cost p50 0.12 ms, p99 0.5 ms, max 5.8 ms inside the send)
        self._log_work = DeferredWork()

    @property
    def name(self) -> str:
        return self.url

    @contextlib.contextmanager
    def burst(self) -> Iterator[None]:  # not nested: host.link.sent.SentFanout makes nested blocks one
        self._log_held = []
        port = self._port
        try:
            with port.corked() if port is not None else contextlib.nullcontext():
                yield
        finally:
            held, self._log_held = self._log_held, None
            if self.framelog is not None:
                t = time.monotonic()  # when the one write went out
                for raw in held:
                    self._log_work.note(self._log_record, "tx", t, raw)

    def _log_record(self, direction: str, t: float, raw: bytes, item: Frame | DecodeError | None = None) -> None:
        """One frame log record, from the loop (:class:`DeferredWork`). A log that cannot be written (disk
        full, the folder gone) is one warning line; the link goes on without it."""
        log = self.framelog
        if log is None:
            return
        try:
            log.write_serial(direction, t, raw, item)
        except Exception as e:  # OSError (disk full, folder gone) or a record the writer refused
            self.framelog = None
            _log.warning("ghostshell: the frame log %s stopped: %s; the link goes on without it", log.path, e)
            with contextlib.suppress(Exception):
                log.close()

    def set_servo_count(self, servo_count: int) -> None:
        self.schema = self._decoder.schema = schema_for(servo_count)
        self._log_work.drain()  # frames noted before the switch decode with the schema they were sent in
        if isinstance(self.framelog, JsonlFrameLog):  # (the drain may have stopped a failing log)
            self.framelog.schema = self.schema

    @property
    def connected(self) -> bool:
        return self._port is not None and not self._port.closed

    @property
    def backlog(self) -> int:
        return self._port.backlog if self._port is not None else 0

    async def connect(self, on_receive: ReceiveHandler, on_lost: LossHandler) -> None:
        self.disconnect()
        if not isinstance(self._url, str):
            self.url = self._url()
        self._decoder.reset()
        self._on_receive = on_receive

        def lost(reason: str) -> None:
            self._port = None
            on_lost(reason)

        try:
            port = SerialPort(self.url, self.baud, self._on_data, lost, force_thread=self.force_thread)
        except (serial.SerialException, OSError, ValueError, TypeError) as e:
            if self._ever_connected:  # it was there: it vanished (reconnects retry this)
                raise LinkDown(f"cannot open {self.url!r}: {e}") from None
            raise LinkConfigError(open_failure(self.url, e)) from e
        self._port = port
        self._ever_connected = True
        try:
            port.write(b"\x00")  # end any partial frame the board may hold
        except (BufferError, ConnectionError) as e:
            self.disconnect()
            raise LinkDown(f"cannot write to {self.url!r}: {e}") from None

    def _on_data(self, data: bytes) -> None:
        items = self._decoder.feed(data)
        if self.framelog is not None:
            t = time.monotonic()
            for item in items:
                self._log_work.note(self._log_record, "rx", t, item.raw, item)
        if items and self._on_receive is not None:
            self._on_receive(items)

    def send(self, msg: Message, seq: int) -> int:
        port = self._port
        if port is None or port.closed:
            raise LinkDown(f"link to {self.url!r} is down")
        raw = encode_frame(msg, seq, self.schema)
        try:
            port.write(raw)
        except BufferError as e:
            raise LinkError(str(e)) from None
        except ConnectionError as e:
            raise LinkDown(f"link to {self.url!r} is down: {e}") from None
        if self._log_held is not None:
            self._log_held.append(raw)
        elif self.framelog is not None:  # decoded from the wire bytes (quantised), from the loop
            self._log_work.note(self._log_record, "tx", time.monotonic(), raw)
        return len(raw)

    def disconnect(self) -> None:
        if self._port is not None:
            self._port.close()
            self._port = None

    def close(self) -> None:
        self.disconnect()
        self._log_work.drain()  # a log that fails meanwhile stops itself (one warning)
        log, self.framelog = self.framelog, None
        if log is not None:
            log.close()
