"""The link supervisor: handshake, time sync, heartbeat and reconnect for one :class:`BoardClient`.

A :class:`Supervisor` keeps a session's link alive; the session (``host.link.session``) sends,
numbers and answers, the supervisor decides when and what to say to keep it up:

* :meth:`Supervisor.connect_once`: connect the transport, HELLO -> CAPS (:meth:`handshake`; the
  robot's wire schema first, then after a SCHEMA_MISMATCH each other schema this build speaks, see
  the session's module docstring), then a burst of TIME_SYNC exchanges;
* :meth:`Supervisor.supervise`: after a loss, reconnect with exponential backoff (0.05 s doubling
  to ``reconnect_max_s``), then the ``on_reconnect`` callbacks;
* :meth:`Supervisor.heartbeat_loop`: a HEARTBEAT whenever nothing else was sent for ``heartbeat_s``;
* :meth:`Supervisor.sync_loop`: a TIME_SYNC exchange every ``sync_interval_s`` (realtime boards),
  feeding :class:`host.link.timesync.ClockSync` (NTP's four timestamps, RFC 5905 section 8).

It owns the futures only it waits on: the HELLO's (answered by CAPS or a NACK) and the TIME_SYNC
replies (by ``t1``). The loops run in the session's task group and never raise.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

from host.link.errors import HandshakeError, LinkError, LinkTimeout, RobotMismatch, SchemaMismatch
from protocol.codec import WIRE_SCHEMAS, WireBoundError, schema_by_hash, schema_for
from protocol.faults import GapDetector
from protocol.messages import Caps, Heartbeat, Hello, TimeSyncReply, TimeSyncRequest

if TYPE_CHECKING:
    from host.link.session import BoardClient

__all__ = ["SYNC_ATTEMPTS", "RobotIdentity", "Supervisor", "host_now_us"]

log = logging.getLogger("host.link")
#: TIME_SYNC exchanges tried at connect before the link counts as failed (each waits 0.5, 1, then 2 s)
SYNC_ATTEMPTS = 6


def host_now_us() -> int:
    """The host clock used for time sync: ``time.monotonic`` in integer microseconds."""
    return time.monotonic_ns() // 1000


@dataclass(frozen=True)
class RobotIdentity:
    """What the host expects CAPS to report: the robot's name, servo count and servo table hash (u32)."""

    name: str
    servo_count: int
    servo_table_hash: int

    def __str__(self) -> str:
        return f"{self.name!r} ({self.servo_count} servos, servo table {self.servo_table_hash:#010x})"


class Supervisor:
    """Keeps ``client``'s link up (module docstring); ``hello_fut`` and ``sync_pending`` are its futures."""

    def __init__(self, client: BoardClient) -> None:
        self.client = client
        self.hello_fut: asyncio.Future[Caps] | None = None
        self.sync_pending: dict[int, asyncio.Future[tuple[TimeSyncReply, int]]] = {}

    def on_caps(self, msg: Caps) -> None:
        """CAPS came: it answers the HELLO in flight, if any."""
        if self.hello_fut is not None and not self.hello_fut.done():
            self.hello_fut.set_result(msg)

    def on_sync_reply(self, msg: TimeSyncReply, t4: int) -> None:
        """A TIME_SYNC reply came at host time ``t4`` (us)."""
        fut = self.sync_pending.get(msg.t1_host_us)
        if fut is not None and not fut.done():
            fut.set_result((msg, t4))

    def refuse_hello(self, error: LinkError) -> bool:
        """The board NACKed a HELLO: fail the HELLO in flight with ``error``; False when none was."""
        if self.hello_fut is None or self.hello_fut.done():
            return False
        self.hello_fut.set_exception(error)
        return True

    def waiting(self) -> list[asyncio.Future[object]]:
        """Every future of this supervisor still pending (the session fails them when the link goes)."""
        futs: list[asyncio.Future[object]] = [*self.sync_pending.values()]  # type: ignore[list-item]
        if self.hello_fut is not None:
            futs.append(self.hello_fut)  # type: ignore[arg-type]
        return futs

    async def connect_once(self) -> None:
        c = self.client
        transport = c._get_transport()
        if c.robot is not None:
            transport.set_servo_count(c.robot.servo_count)
        c._lost.clear()
        await transport.connect(c._on_items, c._on_lost)
        c.port_name = port = transport.name  # a callable spec resolves on connect
        c.link_spec = transport.link_spec
        try:
            caps = await self.handshake()
            c.caps = caps
            c._rx_gaps = GapDetector()  # the board's numbering as from this connection
            c._board_time_seen = caps.board_time_us
            c.clock.clear()
            c._ready = True
            await self.sync_burst()
        except BaseException:
            c._ready = False
            transport.disconnect()
            raise
        c._connected.set()
        log.info(
            "link up on %s: protocol v%d, %d servos, %d Hz, %s", port, caps.protocol_version,
            caps.servo_count, caps.control_rate_hz, "lockstep" if caps.lockstep else "realtime",
        )

    async def hello(self, schema_hash: int) -> Caps:
        """HELLO with ``schema_hash`` until CAPS (re-sent a few times within the timeout: one lost
        frame, either way, must not fail the handshake); a NACK raises (:class:`SchemaMismatch`)."""
        c = self.client
        loop = asyncio.get_running_loop()
        fut: asyncio.Future[Caps] = loop.create_future()
        self.hello_fut = fut
        try:
            tries = 4
            for _ in range(tries):
                c._send(Hello(c.protocol_version, schema_hash, host_now_us()))
                try:
                    return await asyncio.wait_for(asyncio.shield(fut), c.handshake_timeout / tries)
                except TimeoutError:
                    continue
            if not fut.done():
                fut.cancel()
            raise HandshakeError(
                f"no CAPS from {c.port_name!r} within {c.handshake_timeout} s: "
                "is a GhostShell board (ghostshell board, python -m firmware_sim) serving this port?"
            ) from None
        finally:
            self.hello_fut = None

    async def handshake(self) -> Caps:
        c = self.client
        # the robot's schema first (pinned: only it); then, after a SCHEMA_MISMATCH, every other one
        # this build speaks (module docstring)
        first = c.schema_hash if c._schema_pinned else c.schema.hash
        hashes = [first] + ([] if c._schema_pinned else [s.hash for s in WIRE_SCHEMAS if s.hash != first])
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
        if caps.protocol_version != c.protocol_version:
            raise HandshakeError(
                f"board speaks protocol v{caps.protocol_version}, host v{c.protocol_version}: "
                "update the host or the board firmware so both match"
            )
        if caps.schema_hash != h:
            raise HandshakeError(
                f"schema mismatch: board {caps.schema_hash:#010x}, host {h:#010x}: "
                "host and board were built from different protocol definitions; update one side"
            )
        want = c.robot
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
        if c._transport is not None:
            c._transport.set_servo_count(caps.servo_count)
        c.schema_hash = h
        return caps

    async def supervise(self) -> None:
        c = self.client
        while not c._closing:
            await c._lost.wait()
            if c._closing or not c.reconnect:
                return
            delay = 0.05
            while not c._closing:
                await asyncio.sleep(delay)  # backoff between attempts (not synchronisation)
                try:
                    await self.connect_once()
                except LinkError as e:
                    log.debug("reconnect to %s failed: %s", c.port_name, e)
                    c.last_reconnect_error = str(e)  # the loss's own cause stays in last_disconnect_reason
                    delay = min(c.reconnect_max_s, delay * 2)
                    continue
                c.stats.reconnects += 1
                c.last_reconnect_error = ""
                log.warning("link to %s re-established (reconnect #%d)", c.port_name, c.stats.reconnects)
                for cb in list(c.on_reconnect):
                    cb(c)
                break

    async def sync_once(self, timeout: float = 0.5) -> tuple[int, int, int, int]:
        """One TIME_SYNC exchange; returns ``(t1, t2, t3, t4)`` and feeds the estimator (realtime)."""
        c = self.client
        loop = asyncio.get_running_loop()
        t1 = host_now_us()
        while t1 in self.sync_pending:
            t1 += 1
        fut: asyncio.Future[tuple[TimeSyncReply, int]] = loop.create_future()
        self.sync_pending[t1] = fut
        try:
            c._send(TimeSyncRequest(t1))
            reply, t4 = await asyncio.wait_for(fut, timeout)
        except TimeoutError:
            raise LinkTimeout(f"no TIME_SYNC reply within {timeout} s") from None
        finally:
            self.sync_pending.pop(t1, None)
        c._board_time_seen = max(c._board_time_seen, reply.t3_board_us)
        if not c.lockstep:
            c.clock.add(t1, reply.t2_board_us, reply.t3_board_us, t4)
        return t1, reply.t2_board_us, reply.t3_board_us, t4

    async def sync_burst(self) -> None:
        c = self.client
        for _ in range(c.sync_burst if not c.lockstep else 1):
            # a lost probe or reply costs a retry, not the connection (at 5 % frame loss a classic-CAN
            # exchange of 6 frames fails 1 time in 4, three in a row 1 in 50); a board slow to answer (a
            # loaded machine, a board still loading its model) gets longer each time: 0.5, 1, 2, 2, 2, 2 s
            for attempt in range(SYNC_ATTEMPTS):
                try:
                    await self.sync_once(timeout=min(2.0, 0.5 * 2**attempt))
                    break
                except LinkTimeout:
                    if attempt == SYNC_ATTEMPTS - 1:
                        raise
                    c.stats.retries += 1

    async def heartbeat_loop(self) -> None:
        c = self.client
        while True:
            await asyncio.sleep(c.heartbeat_s / 2)
            if c._ready and c.keepalive and time.monotonic() - c._last_tx >= c.heartbeat_s:
                with contextlib.suppress(LinkError):
                    c._send(Heartbeat(host_now_us()))

    async def sync_loop(self) -> None:
        c = self.client
        while True:
            await asyncio.sleep(c.sync_interval_s)
            if c._ready and c.keepalive and not c.lockstep:
                with contextlib.suppress(LinkError):
                    await self.sync_once()
