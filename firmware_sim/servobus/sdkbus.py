"""What the two vendor-SDK buses share: packets out through the SDK, status packets in through it.

The SDKs' group helpers (``GroupSyncRead.rxPacket``) stop at the first servo that does not answer
and throw the rest of the answers away (their ``readRx`` discards packets of other ids while it
waits), so one silent servo would blind the board to all of them. :meth:`SdkBus._collect` instead
takes every status packet the SDK's own parser (``rxPacket``: header, length, checksum/CRC) hands
back after ONE sync read and files it by id; what is missing at the timeout is :data:`TIMEOUT`,
or :data:`CORRUPT` when garbled bytes came instead. Any exception the SDK raises on bytes it did
not expect (an ``IndexError`` in its parser, an ``OSError`` from a vanished adapter) counts as a
garbled answer: a tick always completes.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Mapping, Sequence
from typing import Any

from firmware_sim.servobus.base import CORRUPT, TIMEOUT, MotorBus, PingAnswer, Present

__all__ = ["Answer", "SdkBus"]

#: one status packet: (id, error byte, parameters), or TIMEOUT / CORRUPT
Answer = tuple[int, int, list[int]] | str


class SdkBus(MotorBus):
    """A :class:`MotorBus` over a vendor SDK's ``PortHandler`` + ``PacketHandler``."""

    _port: Any = None
    _ph: Any = None
    #: bytes of a status packet without parameters (STS 6, Dynamixel 11)
    STATUS_BYTES = 6
    TORQUE_ADDR = 40
    GOAL_ADDR = 42
    #: the return delay register (STS 7, Dynamixel 9; 2 us units) and what a servo does before it is read
    RETURN_DELAY_ADDR = 7
    #: bytes an address / a length takes in an instruction (STS 1, Dynamixel 2)
    ADDR_BYTES = 1

    # -- to implement per protocol ---------------------------------------------------------------
    @abstractmethod
    def _make_port(self) -> Any: ...

    @abstractmethod
    def _make_ph(self) -> Any: ...

    @abstractmethod
    def _tx(self, dev_id: int, instruction: int, params: list[int]) -> bool:
        """Send one instruction packet through the SDK (it adds header and checksum); True if sent."""

    @abstractmethod
    def _rx(self) -> Answer:
        """The next status packet through the SDK's parser, or TIMEOUT / CORRUPT."""

    @abstractmethod
    def _sync_read_tx(self, addr: int, n: int, ids: list[int]) -> bool: ...

    def _sync_write(self, addr: int, n: int, data: Mapping[int, list[int]]) -> None:
        """One SYNC WRITE of ``n`` bytes at ``addr`` per id (no answer: both SDKs' ``syncWriteTxOnly``)."""
        param: list[int] = []
        for i, b in data.items():
            param += [i, *b]
        try:
            self._port.is_using = False
            self._ph.syncWriteTxOnly(self._port, addr, n, param, len(param))
        except Exception:  # noqa: BLE001 - the next read reports a bus that went away
            self._port.is_using = False

    @abstractmethod
    def _model_of(self, dev_id: int, ping_params: list[int]) -> int | None:
        """The model number from a ping's answer (Dynamixel carries it) or a READ (STS)."""

    @abstractmethod
    def _present(self, dev_id: int, error: int, params: list[int]) -> Present: ...

    @abstractmethod
    def _read_spec(self) -> tuple[int, int]:
        """(start address, bytes) of the per-tick sync read."""

    # -- shared ----------------------------------------------------------------------------------
    def _le_bytes(self, v: int) -> list[int]:
        return [(v >> (8 * k)) & 0xFF for k in range(self.ADDR_BYTES)]

    def _request(self, dev_id: int, instruction: int, params: list[int], answer_bytes: int) -> Answer:
        """One instruction to one servo and its answer (TIMEOUT when it could not be sent)."""
        self._fresh()
        if not self._tx(dev_id, instruction, params):
            return TIMEOUT
        self._port.setPacketTimeout(self.STATUS_BYTES + answer_bytes)
        return self._answer_from(dev_id)

    def write_register(self, dev_id: int, addr: int, data: list[int]) -> bool:
        """WRITE ``data`` at ``addr`` of one servo; True when it answered without an error bit."""
        r = self._request(dev_id, 3, [*self._le_bytes(addr), *data], 0)
        return isinstance(r, tuple) and not r[1] & 0x7F

    def read_register(self, dev_id: int, addr: int, n: int) -> list[int] | None:
        """READ ``n`` bytes at ``addr`` of one servo; None without a valid answer."""
        r = self._request(dev_id, 2, [*self._le_bytes(addr), *self._le_bytes(n)], n)
        return r[2][:n] if isinstance(r, tuple) and len(r[2]) >= n else None

    def zero_return_delay(self, ids: Sequence[int]) -> float:
        """Write every servo's return delay to 0 (LeRobot does the same at start-up: a status packet then
        follows its instruction at once); a servo that refuses (a Dynamixel with its torque on, an EEPROM
        lock) keeps its own, read back, else the protocol's default. Sets and returns
        :attr:`measured_return_delay_us`, the largest (us)."""
        worst = 0.0
        for i in ids:
            if self.write_register(i, self.RETURN_DELAY_ADDR, [0]):
                continue
            got = self.read_register(i, self.RETURN_DELAY_ADDR, 1)
            worst = max(worst, 2.0 * got[0] if got is not None else self.default_return_delay_us)
        self.measured_return_delay_us = worst
        return worst

    def open(self) -> None:
        port: Any = self.port_handler
        if port is None:
            port = self._make_port()
            port.open_at(self.baud)
        self._port = port
        self._ph = self._make_ph()

    def close(self) -> None:
        p, self._port = self._port, None
        if p is not None and self.port_handler is None:
            try:
                p.closePort()
            except Exception:  # noqa: BLE001 - closing a vanished adapter
                pass

    def _fresh(self) -> None:
        """Before a transaction: no stale answers, the SDK's busy flag down (a failed tx leaves it up)."""
        self._port.is_using = False
        self._port.discard_input()

    def _safe_rx(self) -> Answer:
        try:
            return self._rx()
        except Exception:  # noqa: BLE001 - the SDK's parser on bytes it did not expect, a vanished adapter
            self._port.is_using = False
            return CORRUPT

    def _answer_from(self, dev_id: int) -> Answer:
        """The next answer, which must be ``dev_id``'s: another id's answer is garbled too."""
        r = self._safe_rx()
        if isinstance(r, tuple) and r[0] != dev_id:
            return CORRUPT
        return r

    def _second_answer(self) -> bool:
        """After an answer: does anything more arrive within two status packets' time + 5 ms (a second
        servo with the same id)?"""
        self._port.setPacketTimeoutMillis(2 * self.STATUS_BYTES * self._port.tx_time_per_byte + 5.0)
        return self._safe_rx() != TIMEOUT

    def ping(self, servo_id: int) -> PingAnswer:
        """Ping ``servo_id``: its model number, or the fault that stops the start-up. A second answer is
        confirmed on a quiet line before it is called a duplicate id: a late answer to an earlier ping (a slow
        servo or emulator, the retry after a timeout) reads as a second answer too (CI: a realtime plant on a
        loaded machine answered ping 1 after the board had re-sent it, "answers a ping twice")."""
        ans = self._ping_once(servo_id)
        if ans.fault is not None and "twice" in ans.fault:
            self._drain()
            ans = self._ping_once(servo_id)
        return ans

    def _drain(self) -> None:
        """Read and drop what still arrives until the line is quiet for one answer window (at most 8 answers)."""
        for _ in range(8):
            if not self._second_answer():
                break
        self._fresh()

    def _ping_once(self, servo_id: int) -> PingAnswer:
        self._fresh()
        if not self._tx(servo_id, 1, []):
            return PingAnswer(fault="cannot send on the servo bus")
        self._port.setPacketTimeout(self.STATUS_BYTES + 3)
        r = self._answer_from(servo_id)
        if r == TIMEOUT:
            return PingAnswer(fault="does not answer a ping (missing, unpowered, or another id, baud or protocol)")
        if r == CORRUPT or not isinstance(r, tuple):
            return PingAnswer(fault="answers a ping garbled (two servos with this id, or noise on the bus)")
        if self._second_answer():
            return PingAnswer(fault="answers a ping twice (two servos with this id)")
        model = self._model_of(servo_id, r[2])
        if model is None:
            return PingAnswer(fault="does not tell its model number (garbled answer)")
        return PingAnswer(model=model)

    def set_torque(self, ids: Sequence[int], on: bool) -> None:
        if ids:
            self._sync_write(self.TORQUE_ADDR, 1, {i: [1 if on else 0] for i in ids})

    def write_goals(self, goals: Mapping[int, int]) -> None:
        if goals:
            n = self.goal_bytes
            self._sync_write(self.GOAL_ADDR, n, {i: [(v >> (8 * k)) & 0xFF for k in range(n)]
                                                 for i, v in goals.items()})
            self.counts["sync_writes"] += 1

    def read(self, ids: Sequence[int]) -> dict[int, Present]:
        ids = list(ids)
        if not ids:
            return {}
        addr, n = self._read_spec()
        self._fresh()
        self.counts["sync_reads"] += 1
        if not self._sync_read_tx(addr, n, ids):
            return {i: Present(None, comm=TIMEOUT) for i in ids}
        got = self._collect(ids, n)
        out: dict[int, Present] = {}
        for i in ids:
            a = got[i]
            if isinstance(a, str):
                self.counts["timeouts" if a == TIMEOUT else "corrupt"] += 1
                out[i] = Present(None, comm=a)
                continue
            try:
                out[i] = self._present(i, a[1], a[2])
            except Exception:  # noqa: BLE001 - a well-formed packet whose contents make no sense
                self.counts["corrupt"] += 1
                out[i] = Present(None, comm=CORRUPT)
        return out

    def _collect(self, ids: list[int], n: int) -> dict[int, Answer]:
        """Every status packet after one sync read, by id; each id without a valid one: TIMEOUT, or
        CORRUPT when garbled bytes were seen. Bounded: at most 2 * len(ids) + 2 packets are parsed."""
        pending = set(ids)
        got: dict[int, Answer] = {}
        garbled = False
        for _ in range(2 * len(ids) + 2):
            if not pending:
                break
            r = self._safe_rx()
            if r == TIMEOUT:
                break
            if not isinstance(r, tuple):
                garbled = True
                if self._port.timed_out:
                    break
                continue
            dev_id, error, params = r
            if dev_id in pending:
                pending.discard(dev_id)
                got[dev_id] = (dev_id, error, params) if len(params) >= n else CORRUPT
        for i in pending:
            got[i] = CORRUPT if garbled else TIMEOUT
        return got

    def tick_bytes(self, n: int) -> int:
        addr, nbytes = self._read_spec()
        return (self.STATUS_BYTES + 2 + n) + n * (self.STATUS_BYTES + nbytes) + (
            self.STATUS_BYTES + 2 + n * (1 + self.goal_bytes))
