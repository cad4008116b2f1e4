"""The link supervisor: handshake, time sync, heartbeat and reconnect for one session.

A :class:`Supervisor` keeps a session's link alive; the session (``host.link.core``) sends,
numbers and answers, the supervisor decides when and what to say to keep it up:

* :meth:`Supervisor.connect_once`: connect the transport, HELLO -> CAPS (:meth:`handshake`; the
  robot's wire schema first, then after a SCHEMA_MISMATCH each other schema this build speaks, unless
  a hash is pinned), then a burst of TIME_SYNC exchanges;
* :meth:`Supervisor.supervise`: after a loss, reconnect with exponential backoff (0.05 s doubling
  to ``reconnect_max_s``), then the session's ``reconnected`` (its ``on_reconnected`` callbacks);
* :meth:`Supervisor.heartbeat_loop`: a HEARTBEAT whenever nothing else was sent for ``heartbeat_s``
  (realtime boards: a lockstep board's watchdog runs on its own clock, which only the host's frames and
  ADVANCEs move, and a message sent on wall time would make the run depend on the host's timing);
* :meth:`Supervisor.sync_loop`: a TIME_SYNC exchange every ``sync_interval_s`` (realtime boards),
  feeding the board clock's :class:`host.link.timesync.ClockSync` (NTP's four timestamps, RFC 5905
  section 8; :class:`host.link.board_time.BoardClock`).

It knows the session only as :class:`SupervisedSession` (a Protocol: what it reads, sets and calls),
so this module does not import the session; the handshake's and the keep-alive's settings are its
own attributes. It owns the replies only it waits on
(:class:`host.link.waiting.Reply`): the HELLO's (answered by CAPS or a NACK) and the TIME_SYNC
replies (by ``t1``). The loops run in the client's anyio task group (:mod:`host.link.background`) and
never raise.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import time
from dataclasses import dataclass
from typing import Any, Protocol

import anyio

from host.link.board_time import BoardClock
from host.link.errors import HandshakeError, LinkError, LinkTimeout, NackError, RobotMismatch, SchemaMismatch
from host.link.timesync import host_now_us
from host.link.transports.base import Transport
from host.link.waiting import Flag, Reply
from protocol.codec import WIRE_SCHEMAS, WireBoundError, WireSchema, schema_by_hash, schema_for
from protocol.messages import (PROTOCOL_VERSION, Ack, Caps, Config, ConfigKey, Heartbeat, Hello, Message, TimeSyncReply,
                               TimeSyncRequest)
from protocol.wiremodel import WireModel

__all__ = ["HEARTBEAT_S", "SYNC_ATTEMPTS", "RobotIdentity", "SupervisedSession", "Supervisor", "host_now_us"]

log = logging.getLogger("host.link")
#: TIME_SYNC exchanges tried at connect before the link counts as failed; the first waits
#: ``SYNC_FIRST_WAIT_S``, each next one twice the one before, at most ``SYNC_WAIT_MAX_S`` (9.1 s in all).
#: The board has just answered a HELLO, so it is up: a native one answers in ~1 ms, a slow one (QEMU,
#: User-Mode Linux, a loaded machine) costs a retry or two. With a fixed 0.5, 1, then 2 s each, a lost
#: probe or reply cost 0.5-2 s: seeded drop=0.05 over SLCAN lost 5 in a row, 7.5 s of connect (now 3.1).
SYNC_ATTEMPTS = 8
SYNC_FIRST_WAIT_S = 0.1
SYNC_WAIT_MAX_S = 2.0
#: wire bytes a TIME_SYNC exchange may take over a slow line (:meth:`Supervisor.sync_wait_s`): the request
#: (17) and reply (33), and a TELEMETRY + SIM_STATE pair the reply may queue behind (163 for 12 servos; the
#: rest leaves room for a robot of 32)
SYNC_QUEUE_BYTES = 300
#: HELLO is sent again after this, then after twice the wait before, until the handshake timeout: any
#: CAPS answers it (HELLO is stateless on the board), so an early re-send costs one frame, never a reply
HELLO_FIRST_RETRY_S = 0.25
#: a HEARTBEAT whenever nothing else was sent for this long (s): four per 200 ms of the board's default watchdog
HEARTBEAT_S = 0.05


@dataclass(frozen=True)
class RobotIdentity:
    """What the host expects CAPS to report: the robot's name, servo count and servo table hash (u32)."""

    name: str
    servo_count: int
    servo_table_hash: int

    def __str__(self) -> str:
        return f"{self.name!r} ({self.servo_count} servos, servo table {self.servo_table_hash:#010x})"


class SupervisedSession(Protocol):
    """What the supervisor needs of the session (:class:`host.link.core.LinkSession` is one)."""

    port_name: str
    reconnect: bool
    closing: bool
    ready: bool
    last_tx: float
    last_reconnect_error: str
    tx_wire: WireModel | None
    up: Flag
    lost: Flag

    @property
    def transport(self) -> Transport | None: ...
    async def attach(self, servo_count: int | None) -> Transport: ...
    def transmit(self, msg: Message) -> int: ...
    async def request(self, msg: Message) -> Ack: ...
    def link_up(self, caps: Caps) -> None: ...
    def count_retry(self) -> None: ...
    def reconnected(self) -> None: ...


class Supervisor:
    """Keeps ``client``'s link up (module docstring); ``hello_fut`` and ``sync_pending`` are its replies.

    ``clock`` is the board clock its TIME_SYNC exchanges feed. The handshake: ``robot`` is what CAPS
    must report (None: any), ``schema`` the wire schema tried first, ``schema_hash`` pins the hash HELLO
    carries (only it is tried; tests), ``handshake_timeout`` (s) bounds each schema's HELLO. Keep-alive:
    a HEARTBEAT after ``heartbeat_s`` without a send, a TIME_SYNC every ``sync_interval_s`` (realtime
    boards, while ``keepalive``), ``sync_burst`` exchanges at connect; reconnect backoff up to
    ``reconnect_max_s``.
    """

    def __init__(self, client: SupervisedSession, clock: BoardClock, *, robot: RobotIdentity | None = None,
                 schema: WireSchema, schema_hash: int | None = None, protocol_version: int = PROTOCOL_VERSION,
                 handshake_timeout: float = 3.0, reconnect_max_s: float = 1.0, sync_burst: int = 8,
                 heartbeat_s: float = HEARTBEAT_S, sync_interval_s: float = 0.5,
                 link_config: tuple[tuple[ConfigKey, int], ...] = ()) -> None:
        self.client, self.clock = client, clock
        #: CONFIGs sent after CAPS, before TIME_SYNC, on every connect (a slow line's watchdog and report
        #: rate: host.motion.line_cadence)
        self.link_config = link_config
        self.robot, self.schema, self.protocol_version = robot, schema, protocol_version
        self.schema_pinned = schema_hash is not None
        #: the schema hash HELLO carries (the one the board accepted, after a handshake)
        self.schema_hash = schema.hash if schema_hash is None else schema_hash
        self.handshake_timeout, self.reconnect_max_s = handshake_timeout, reconnect_max_s
        self.sync_burst_n, self.heartbeat_s, self.sync_interval_s = sync_burst, heartbeat_s, sync_interval_s
        self.keepalive = True  # heartbeat + periodic sync; turn off to let the watchdog fire
        self.hello_fut: Reply[Caps] | None = None
        #: every HELLO of the current handshake (re-sends included): sequence number -> its schema hash
        self.hellos_sent: dict[int, int] = {}
        self.hello_hash: int | None = None  # the schema hash of the HELLO in flight
        #: TIME_SYNC replies awaited, by ``t1`` (any object with a future's ``done``/``set_result`` fits)
        self.sync_pending: dict[int, Any] = {}

    def awaiting_caps(self) -> bool:
        """A HELLO is in flight: the next CAPS answers it."""
        return self.hello_fut is not None and not self.hello_fut.done()

    def on_caps(self, msg: Caps) -> None:
        """CAPS came: it answers the HELLO in flight, if any."""
        if self.hello_fut is not None and not self.hello_fut.done():
            self.hello_fut.set_result(msg)

    def slow_line_note(self) -> str:
        """Why a reply may not have come over a line the host models (``BoardClient(wire_baud=...)``, the
        emulated board's ``--baud``): its rate, which may be too slow for the handshake and the board's
        reports; "" without a model (a reply that does not come then has other causes)."""
        line = self.client.tx_wire
        if line is None or line.baud is None:
            return ""
        return (f"the line is modelled at {line.baud} baud, which may be too slow to "
                "carry the handshake and the board's reports in time (the board's warnings say whether they fit)")

    def on_sync_reply(self, msg: TimeSyncReply, t4: int, nbytes: int = 0) -> None:
        """A TIME_SYNC reply of ``nbytes`` wire bytes came at host time ``t4`` (us)."""
        fut = self.sync_pending.get(msg.t1_host_us)
        if fut is not None and not fut.done():
            fut.set_result((msg, t4, nbytes))

    def refuse_hello(self, error: LinkError, ack_seq: int) -> bool:
        """The board NACKed the HELLO sent as ``ack_seq``: fail the HELLO in flight with ``error`` when it
        is one of its sends. A NACK of an earlier HELLO of this handshake (a re-send the board answered
        late, for a schema hash already refused) is ignored: it must not fail the next hash's HELLO.
        True when the NACK was a HELLO's of this handshake (handled here); False otherwise."""
        refused = self.hellos_sent.get(ack_seq)
        if refused is None:
            return False
        if refused == self.hello_hash and self.hello_fut is not None and not self.hello_fut.done():
            self.hello_fut.set_exception(error)
        return True

    def fail_all(self, exc: LinkError) -> None:
        """The link went down: the HELLO and TIME_SYNC exchanges in flight fail with ``exc``."""
        futs: list[Any] = [*self.sync_pending.values()]
        if self.hello_fut is not None:
            futs.append(self.hello_fut)
        for fut in futs:
            if not fut.done():
                fut.set_exception(exc)
                fut.exception()  # mark retrieved: nobody may be awaiting it
        self.sync_pending.clear()

    async def connect_once(self) -> None:
        """Connect, handshake and sync once (no retries); raises :class:`LinkError` on failure."""
        c = self.client
        transport = await c.attach(self.robot.servo_count if self.robot is not None else None)
        port = c.port_name
        try:
            caps = await self.handshake()
            c.link_up(caps)
            if self.link_config:
                await self.configure(caps)
            await self.sync_burst()
        except BaseException:
            c.ready = False
            transport.disconnect()
            raise
        c.up.set()
        log.info(
            "link up on %s: protocol v%d, %d servos, %d Hz, %s", port, caps.protocol_version,
            caps.servo_count, caps.control_rate_hz, "lockstep" if caps.lockstep else "realtime",
        )

    async def configure(self, caps: Caps) -> None:
        """Send :attr:`link_config`'s CONFIGs, each ACKed before the next (the watchdog first, so the longer
        one covers the TIME_SYNC burst on a slow line); a changed report rate is taken into ``caps`` (the
        session's link is brought up again with it). A NACK raises :class:`HandshakeError` naming the key."""
        c = self.client
        rate = None
        for key, value in self.link_config:
            try:
                await c.request(Config(key, value))
            except NackError as e:
                raise HandshakeError(f"the board on {c.port_name} refused CONFIG {key.name}={value} ({e}), which "
                                     "this line needs (docs/concepts/wire.md, slow lines)") from None
            if key is ConfigKey.TELEMETRY_RATE_HZ:
                rate = value
        if rate is not None and rate != caps.telemetry_rate_hz:
            c.link_up(dataclasses.replace(caps, telemetry_rate_hz=rate))

    async def hello(self, schema_hash: int) -> Caps:
        """HELLO with ``schema_hash`` until CAPS (re-sent a few times within the timeout: one lost
        frame, either way, must not fail the handshake); a NACK raises (:class:`SchemaMismatch`)."""
        c = self.client
        fut: Reply[Caps] = Reply()
        self.hello_fut = fut
        self.hello_hash = schema_hash  # only a NACK of a HELLO with this hash fails it (refuse_hello)
        try:
            deadline = anyio.current_time() + self.handshake_timeout
            wait = HELLO_FIRST_RETRY_S
            while True:
                self.hellos_sent[c.transmit(Hello(self.protocol_version, schema_hash, host_now_us()))] = schema_hash
                left = deadline - anyio.current_time()
                if left <= 0:
                    break
                if await fut.wait(min(wait, left)):
                    return fut.result()
                wait *= 2
            fut.cancel()
            why = self.slow_line_note() or "is a GhostShell board (ghostshell board, python -m firmware_sim) serving this port?"
            raise HandshakeError(f"no CAPS from {c.port_name!r} within {self.handshake_timeout} s: {why}") from None
        finally:
            self.hello_fut = None

    async def handshake(self) -> Caps:
        c = self.client
        self.hellos_sent.clear()
        # the robot's schema first (pinned: only it); then, after a SCHEMA_MISMATCH, every other one
        # this build speaks (module docstring)
        first = self.schema_hash if self.schema_pinned else self.schema.hash
        hashes = [first] + ([] if self.schema_pinned else [s.hash for s in WIRE_SCHEMAS if s.hash != first])
        caps = None
        refused: SchemaMismatch | None = None
        for h in hashes:
            try:
                caps = await self.hello(h)
            except SchemaMismatch as e:
                refused = refused or e
                continue
            break
        if caps is None:
            assert refused is not None
            raise refused
        if caps.protocol_version != self.protocol_version:
            raise HandshakeError(
                f"board speaks protocol v{caps.protocol_version}, host v{self.protocol_version}: "
                "update the host or the board firmware so both match"
            )
        if caps.schema_hash != h:
            raise HandshakeError(
                f"schema mismatch: board {caps.schema_hash:#010x}, host {h:#010x}: "
                "host and board were built from different protocol definitions; update one side"
            )
        want = self.robot
        board = RobotIdentity(caps.robot, caps.servo_count, caps.servo_table_hash)
        if want is not None and board != want:
            raise RobotMismatch(
                f"the board on {c.port_name} drives robot {board}, but this host was started for {want}: "
                "start host and board with the same --robot (and the same robot files)")
        try:
            board_schema = schema_for(caps.servo_count)
        except WireBoundError as e:
            raise HandshakeError(f"the board on {c.port_name} reports robot {board}: {e}") from None
        if schema_by_hash(h) not in (None, board_schema):
            raise HandshakeError(f"the board on {c.port_name} reports robot {board} but speaks the wire schema "
                                 f"{h:#010x} of another servo count ({board_schema!r} expected): a broken board build")
        if c.transport is not None:
            c.transport.set_servo_count(caps.servo_count)
        self.schema_hash = h
        return caps

    async def supervise(self) -> None:
        c = self.client
        while not c.closing:
            await c.lost.wait()
            if c.closing or not c.reconnect:
                return
            delay = 0.05
            while not c.closing:
                await anyio.sleep(delay)  # backoff between attempts (not synchronisation)
                try:
                    await self.connect_once()
                except LinkError as e:
                    log.debug("reconnect to %s failed: %s", c.port_name, e)
                    c.last_reconnect_error = str(e)  # the loss's own cause stays in last_disconnect_reason
                    delay = min(self.reconnect_max_s, delay * 2)
                    continue
                c.reconnected()
                break

    async def sync_once(self, timeout: float = 0.5) -> tuple[int, int, int, int]:
        """One TIME_SYNC exchange; returns ``(t1, t2, t3, t4)`` and feeds the estimator (realtime)."""
        c = self.client
        t1 = host_now_us()
        while t1 in self.sync_pending:
            t1 += 1
        fut: Reply[tuple[TimeSyncReply, int, int]] = Reply()
        self.sync_pending[t1] = fut
        try:
            c.transmit(TimeSyncRequest(t1))
            # the part of the uplink the host's line model accounts for (queue + the request's own bytes)
            wire_us = c.tx_wire.busy_s(time.monotonic()) * 1e6 if c.tx_wire is not None else 0.0
            reply, t4, reply_bytes = await fut.get(timeout)
        except TimeoutError:
            note = self.slow_line_note()
            raise LinkTimeout(f"no TIME_SYNC reply within {timeout} s" + (f": {note}" if note else "")) from None
        finally:
            if self.sync_pending.get(t1) is fut:
                del self.sync_pending[t1]
            fut.cancel()
        clock = self.clock
        clock.saw(reply.t3_board_us)
        if not clock.lockstep:
            # the board models its line at the same rate both ways: the reply's own bytes took their wire
            # time too. Its wait behind the board's earlier bytes is not in the leg: the emulated board
            # stamps t3 as the reply's first byte goes on its line (firmware_sim.server); a board that
            # stamps it sooner adds that wait, and such a sample's longer round trip ranks it low in the fit
            down_us = c.tx_wire.wire_s(reply_bytes) * 1e6 if c.tx_wire is not None and wire_us > 0 else 0.0
            clock.sync.add(t1, reply.t2_board_us, reply.t3_board_us, t4, wire_us=wire_us, wire_down_us=down_us)
        return t1, reply.t2_board_us, reply.t3_board_us, t4

    def sync_wait_s(self, wait_s: float) -> float:
        """How long a TIME_SYNC exchange may take (s): ``wait_s``, or over a modelled slow line the wire time of
        a request, its reply and :data:`SYNC_QUEUE_BYTES` the reply may queue behind, if longer. At 2 400
        baud an exchange is 208 ms of wire and a report pair 680 ms more: with 0.1 s a C firmware board,
        which drops no report, answered every probe too late (29 re-sent, 16 s of connect, and the
        board's watchdog held for the 2-s waits between)."""
        line = self.client.tx_wire
        if line is None or line.baud is None:
            return wait_s
        return max(wait_s, line.wire_s(SYNC_QUEUE_BYTES))

    async def sync_burst(self) -> None:
        """``sync_burst`` TIME_SYNC exchanges (one in lockstep), each tried up to :data:`SYNC_ATTEMPTS` times."""
        c = self.client
        first = self.sync_wait_s(SYNC_FIRST_WAIT_S)
        for _ in range(self.sync_burst_n if not self.clock.lockstep else 1):
            # a lost probe or reply costs a retry, not the connection (at 5 % frame loss a classic-CAN
            # exchange of 6 frames fails 1 time in 4, three in a row 1 in 50); a board slow to answer (a
            # loaded machine) gets longer each time (SYNC_ATTEMPTS)
            for attempt in range(SYNC_ATTEMPTS):
                try:
                    await self.sync_once(timeout=min(max(SYNC_WAIT_MAX_S, first), first * 2**attempt))
                    break
                except LinkTimeout:
                    if attempt == SYNC_ATTEMPTS - 1:
                        raise
                    c.count_retry()

    async def heartbeat_loop(self) -> None:
        """A HEARTBEAT whenever nothing else was sent for ``heartbeat_s`` (realtime boards only: in lockstep
        nothing is sent on wall time, see the module docstring)."""
        c = self.client
        while True:
            await anyio.sleep(self.heartbeat_s / 2)
            if (c.ready and self.keepalive and not self.clock.lockstep
                    and time.monotonic() - c.last_tx >= self.heartbeat_s):
                with contextlib.suppress(LinkError):
                    c.transmit(Heartbeat(host_now_us()))

    async def sync_loop(self) -> None:
        c = self.client
        while True:
            await anyio.sleep(self.sync_interval_s)
            if c.ready and self.keepalive and not self.clock.lockstep:
                with contextlib.suppress(LinkError):
                    await self.sync_once(self.sync_wait_s(0.5))
