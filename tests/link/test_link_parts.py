"""The session's parts on their own: request bookkeeping, replies, telemetry fan-out (no board; no sleeps).

The whole link with a real board is in test_e2e.py, test_seq_wrap.py and tests/can; these pin the
contracts of host.link.requests, host.link.waiting and host.link.telemetry that the session relies on.
Time never passes in them: a per-try timeout of 0 s expires at the first checkpoint, and a
subscriber is known to wait once every task is blocked (anyio.wait_all_tasks_blocked).
"""

from __future__ import annotations

from collections import deque

import anyio
import anyio.lowlevel
import pytest


from host.link.errors import LinkDown, LinkTimeout, NackError
from host.link.requests import RequestTable, RetransmitTimeout
from host.link.telemetry import TelemetryFanout
from host.link.waiting import Flag, Reply
from protocol.messages import Ack, Estop, FaultFlags, MsgType, Nack, NackReason, Telemetry

pytestmark = pytest.mark.timeout(30)


def _tel(t_us: int) -> Telemetry:
    return Telemetry(t_us, (0.0,), (0.0,), (0.0,), (0.0, 0.0, 0.0), FaultFlags.NONE, 0, 0, 0, 0, 0)


def test_a_request_is_answered_by_the_ack_to_any_copy_and_counts_its_retries() -> None:
    async def main() -> None:
        retries: list[int] = []
        table = RequestTable(lambda: retries.append(1))
        sent: list[int] = []

        def send(msg: object) -> int:
            seq = len(sent)
            sent.append(seq)
            if seq == 2:  # the third copy: the board acknowledges the FIRST one (its ACK was late)
                table.on_ack(Ack(0, MsgType.ESTOP))
            return seq

        ack = await table.request(send, Estop(), per_try=0, attempts=5)
        assert ack == Ack(0, MsgType.ESTOP) and sent == [0, 1, 2] and len(retries) == 2
        assert table.pending == {}  # nothing left keyed by the copies

    anyio.run(main, backend="asyncio")


def test_a_nack_fails_the_request_and_no_reply_is_a_timeout() -> None:
    async def main() -> None:
        table = RequestTable()

        seqs = iter([7, 8])

        def refuse(msg: object) -> int:
            seq = next(seqs)
            if seq == 8:  # the second copy goes out as the board's refusal of the first comes in
                table.on_nack(Nack(7, MsgType.ESTOP, NackReason.BAD_VALUE, "no"))
            return seq

        with pytest.raises(NackError) as e:
            await table.request(refuse, Estop(), per_try=0, attempts=3)
        assert e.value.reason == NackReason.BAD_VALUE and table.frame_nack(7) is None  # a request's NACK is no frame NACK
        with pytest.raises(LinkTimeout, match=r"seq 1, 2\) after 2 attempt"):
            more = iter([1, 2])
            await table.request(lambda m: next(more), Estop(), per_try=0, attempts=2)

    anyio.run(main, backend="asyncio")


def test_reusing_a_sequence_number_forgets_its_old_nack_and_answers_its_waiter_with_none() -> None:
    async def main() -> None:
        table = RequestTable()
        assert table.on_nack(Nack(5, MsgType.SERVO_FRAME, NackReason.LATE)) is False
        assert table.frame_nack(5 + 0x10000) is not None  # 16-bit numbers
        got: list[Nack | None] = []
        async with anyio.create_task_group() as tg:
            async def wait() -> None:
                got.append(await table.wait_frame_nack(6, 60))

            tg.start_soon(wait)
            await anyio.wait_all_tasks_blocked()
            table.forget_seq(5)
            table.forget_seq(6)  # frame 6 never got a NACK in a whole lap
        assert got == [None] and table.frame_nack(5) is None and table.nack_waiters == []

    anyio.run(main, backend="asyncio")


def test_a_lost_link_fails_what_waits_and_a_reply_takes_one_answer() -> None:
    async def main() -> None:
        table = RequestTable()
        r: Reply[Ack] = Reply()
        table.expect(3, r)
        table.fail_all(LinkDown("gone"))
        assert await r.wait(0) and isinstance(r.exception(), LinkDown) and table.pending == {}
        with pytest.raises(LinkDown):
            r.result()
        r2: Reply[int] = Reply()
        assert await r2.wait(0) is False  # no answer: a timeout, and waiting again is allowed
        r2.set_result(4)
        assert await r2.wait(0) and r2.result() == 4
        with pytest.raises(RuntimeError):
            r2.set_result(5)

    anyio.run(main, backend="asyncio")


def test_a_flag_can_be_cleared_and_waited_for_again() -> None:
    async def main() -> None:
        flag = Flag()
        woke: list[bool] = []
        async with anyio.create_task_group() as tg:
            async def wait() -> None:
                await flag.wait()
                woke.append(flag.is_set())

            tg.start_soon(wait)
            await anyio.wait_all_tasks_blocked()
            assert woke == []
            flag.set()
        flag.clear()
        with anyio.move_on_after(0) as scope:
            await flag.wait()
        assert woke == [True] and scope.cancelled_caught

    anyio.run(main, backend="asyncio")


def test_a_slow_subscriber_loses_the_oldest_reports_and_waiters_get_the_first_match() -> None:
    async def main() -> None:
        fan = TelemetryFanout(queue_size=2)
        got: list[int] = []
        async with anyio.create_task_group() as tg:
            async def consume() -> None:
                async for t in fan.subscribe():
                    got.append(t.board_time_us)
                    if len(got) == 3:
                        return

            tg.start_soon(consume)
            await anyio.wait_all_tasks_blocked()  # subscribed and waiting
            w = fan.waiter(lambda t: t.board_time_us >= 3)
            fan.on_telemetry(_tel(1))  # handed straight to the waiting subscriber
            for t in (2, 3, 4):
                fan.on_telemetry(_tel(t))  # the subscriber has not run: a stream of 2 keeps 3 and 4
            assert w.done() and w.result().board_time_us == 3
        assert got == [1, 3, 4] and fan.latest == _tel(4)
        fan.forget(w)
        await anyio.lowlevel.checkpoint()

    anyio.run(main, backend="asyncio")


def test_the_retransmit_timeout_follows_rfc_6298() -> None:
    rto = RetransmitTimeout(min_s=0.001, max_s=1.0)
    assert rto.timeout_s() == 1.0  # before any sample: the longest wait
    rto.sample(0.010)  # SRTT = R, RTTVAR = R/2
    assert (rto.srtt, rto.rttvar) == pytest.approx((0.010, 0.005)) and rto.timeout_s() == pytest.approx(0.030)
    rto.sample(0.020)  # RTTVAR = 3/4·0.005 + 1/4·|0.010 - 0.020|, SRTT = 7/8·0.010 + 1/8·0.020
    assert (rto.srtt, rto.rttvar) == pytest.approx((0.01125, 0.00625))
    assert rto.timeout_s() == pytest.approx(0.01125 + 4 * 0.00625)
    assert RetransmitTimeout(min_s=0.1).timeout_s() == 1.0
    clamped = RetransmitTimeout(min_s=0.1, max_s=1.0)
    clamped.sample(0.002)
    assert clamped.timeout_s() == 0.1  # a ~2 ms link still waits 0.1 s
    clamped.sample(30.0)
    assert clamped.timeout_s() == 1.0
    with pytest.raises(ValueError):
        RetransmitTimeout(min_s=0.0)


def test_with_a_measured_round_trip_a_lost_request_is_re_sent_soon_and_backs_off_within_the_same_patience() -> None:
    """Trio's MockClock (virtual time, jumping whenever every task waits): the copies of a request nobody
    answers go out 0.1, 0.2, 0.4, 0.8, 1.0 s apart, and it fails after attempts × per_try = 3 s, as
    without the timer; every answer is a round-trip sample timed from the copy it names."""
    import trio.testing

    async def main() -> None:
        table = RequestTable()
        rto = RetransmitTimeout(min_s=0.1, max_s=1.0)
        rto.sample(0.002)
        sent_at: list[float] = []

        def lost(msg: object) -> int:
            sent_at.append(anyio.current_time())
            return len(sent_at) - 1

        t0 = anyio.current_time()
        with pytest.raises(LinkTimeout, match=r"after 6 attempt\(s\) in 3.00 s"):
            await table.request(lost, Estop(), per_try=1.0, attempts=3, rto=rto)
        assert [round(t - t0, 6) for t in sent_at] == [0.0, 0.1, 0.3, 0.7, 1.5, 2.5]
        assert anyio.current_time() - t0 == pytest.approx(3.0)

        copies: list[int] = []
        async with anyio.create_task_group() as tg:
            async def ack_after(seq: int, delay: float) -> None:
                await anyio.sleep(delay)
                table.on_ack(Ack(seq, MsgType.ESTOP))

            def answered_in_4_ms(msg: object) -> int:
                tg.start_soon(ack_after, 0, 0.004)
                return 0

            await table.request(answered_in_4_ms, Estop(), per_try=1.0, attempts=3, rto=rto)
            assert rto.samples == 2 and rto.srtt == pytest.approx(7 / 8 * 0.002 + 1 / 8 * 0.004)

            def first_copy_answered_late(msg: object) -> int:
                copies.append(len(copies))
                if len(copies) == 1:  # its ACK takes 0.3 s: after the re-send at ~0.1 s
                    tg.start_soon(ack_after, 0, 0.3)
                return copies[-1]

            await table.request(first_copy_answered_late, Estop(), per_try=1.0, attempts=3, rto=rto)
        # two copies went out; the ACK names the first, so the sample is its 0.3 s, not the 0.2 s since
        # the second: a timer that fired too early grows with the next answer
        assert copies == [0, 1] and rto.samples == 3
        assert rto.srtt == pytest.approx(7 / 8 * (7 / 8 * 0.002 + 1 / 8 * 0.004) + 1 / 8 * 0.3)
        assert rto.timeout_s() > 0.1

    anyio.run(main, backend="trio", backend_options={"clock": trio.testing.MockClock(autojump_threshold=0)})


def test_a_nudge_takes_a_report_as_lost_after_four_times_the_slowest_recent_one() -> None:
    from host.link.telemetry_waits import TelemetryWaits

    w = object.__new__(TelemetryWaits)
    w.report_latencies = deque(maxlen=16)  # as BoardClient makes it
    assert w.nudge_raise_s() == TelemetryWaits.NUDGE_RAISE_S == 1.0  # nothing measured yet
    w._report_latency(0.002)  # a native board: 2 ms
    assert w.nudge_raise_s() == 2 * TelemetryWaits.NUDGE_S  # never under two nudges
    w._report_latency(0.15)  # a slow one (QEMU) among the recent reports
    assert w.nudge_raise_s() == pytest.approx(0.6)
    w._report_latency(0.9)
    assert w.nudge_raise_s() == 1.0  # never over NUDGE_RAISE_S
    for _ in range(16):  # the slow reports fall out of the last 16
        w._report_latency(0.002)
    assert w.nudge_raise_s() == 0.2


@pytest.mark.parametrize("reply_after_s", [0.1, 0.3, 1.0])
def test_a_late_nack_of_a_refused_hash_does_not_fail_the_next_hashs_hello(reply_after_s: float) -> None:
    """A host without a robot tries the 16-servo schema's hash, then the 32-servo one's. HELLO is re-sent
    after 0.25 s, so a board slower than that gets two HELLOs of the refused hash and NACKs both; the
    second NACK came while the next hash's HELLO was in flight and failed it (the reviewer's case: a
    32-servo board unreachable by ``ghostshell estop``). Only a NACK of the HELLO in flight counts.
    Virtual time (trio's MockClock): the board answers every HELLO ``reply_after_s`` later."""
    import trio.testing

    from host.link.board_time import BoardClock
    from host.link.errors import SchemaMismatch
    from host.link.supervisor import Supervisor
    from protocol.codec import WIRE_SCHEMA_16, WIRE_SCHEMA_32
    from protocol.messages import PROTOCOL_VERSION, Caps, Hello

    sent: list[int] = []
    sups: list[Supervisor] = []

    class Client:  # what Supervisor.handshake reads of a session
        port_name = "fake"
        transport = None

        def __init__(self, tg: anyio.abc.TaskGroup) -> None:
            self.tg = tg

        def transmit(self, msg: Hello) -> int:
            seq = len(sent)
            sent.append(msg.schema_hash)

            async def answer() -> None:
                await anyio.sleep(reply_after_s)
                if msg.schema_hash == WIRE_SCHEMA_32.hash:
                    sups[0].on_caps(Caps(PROTOCOL_VERSION, WIRE_SCHEMA_32.hash, 17, 500, 64, 50, 0, True, "big", 1))
                else:
                    sups[0].refuse_hello(SchemaMismatch("board refused the handshake: SCHEMA_MISMATCH"), seq)

            self.tg.start_soon(answer)
            return seq

    async def main() -> Caps:
        async with anyio.create_task_group() as tg:
            client = Client(tg)
            sups.append(Supervisor(client, BoardClock(client), schema=WIRE_SCHEMA_16,  # type: ignore[arg-type]
                                   protocol_version=PROTOCOL_VERSION, handshake_timeout=3.0))
            caps = await sups[0].handshake()
            tg.cancel_scope.cancel()
        return caps

    caps = anyio.run(main, backend="trio", backend_options={"clock": trio.testing.MockClock(autojump_threshold=0)})
    assert caps.schema_hash == WIRE_SCHEMA_32.hash and caps.robot == "big"
    assert sent.count(WIRE_SCHEMA_16.hash) >= (2 if reply_after_s > 0.25 else 1), sent  # the case did arise


def test_the_boards_numbering_restarts_at_the_caps_so_frames_that_overtook_it_are_no_gap() -> None:
    """Over CAN a CAPS is an ISO-TP transfer that fixed TELEMETRY frames overtake, and the SIM_STATE
    before it can come after it. The host restarted its gap count when the handshake finished (later,
    under load), from whatever came next: a late SIM_STATE made the TELEMETRY already received look
    lost. It now restarts at the CAPS itself."""
    from host.link import BoardClient
    from host.link.receive import REORDER_DEPTH
    from protocol.framing import Frame
    from protocol.messages import PROTOCOL_VERSION, Caps, SimState

    def tel(seq: int) -> Frame:
        msg = Telemetry(seq * 1000, (0.0,), (0.0,), (0.0,), (0.0, 0.0, 0.0), FaultFlags(0), 0, 0, 0, 0, 0)
        return Frame(seq, MsgType.TELEMETRY, msg, b"")

    caps = Caps(PROTOCOL_VERSION, 0, 1, 500, 64, 50, 10_000, True, "chain1", 0)
    client = BoardClient("pty")
    client.supervisor.hello_fut = Reply()
    client.receiver.on_items([tel(7), tel(8), tel(11), Frame(10, MsgType.CAPS, caps, b"")])
    assert client.supervisor.hello_fut.done() and client.supervisor.hello_fut.result() is caps
    client.session.link_up(caps)  # the handshake's end, after the frames above were counted
    sim = SimState(9000, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0))
    client.receiver.on_items([Frame(9, MsgType.SIM_STATE, sim, b""), tel(12), tel(13)])
    assert client.stats.seq_gaps == 0
    # a SIM_STATE overtaken at the end of a run is no loss while it may still come; a real loss counts
    # once REORDER_DEPTH later messages have come
    client.receiver.on_items([tel(15)])
    assert client.stats.seq_gaps == 0
    client.receiver.on_items([tel(s) for s in range(16, 16 + REORDER_DEPTH)])
    assert client.stats.seq_gaps == 1
    client.receiver.on_items([Frame(14, MsgType.SIM_STATE, sim, b"")])  # it was late after all
    assert client.stats.seq_gaps == 0


def test_the_fanout_counts_each_watchdog_hold_the_reports_raise() -> None:
    """``TelemetryFanout.watchdog_holds``: rising WATCHDOG_HOLD edges only (a hold that lasts several
    reports is one; another fault bit changing during it is not a new one)."""
    import dataclasses

    fan = TelemetryFanout()
    hold, estop = FaultFlags.WATCHDOG_HOLD, FaultFlags.ESTOP
    for t, flags in enumerate([FaultFlags.NONE, hold, hold, hold | estop, FaultFlags.NONE, hold, FaultFlags.NONE]):
        fan.on_telemetry(dataclasses.replace(_tel(t * 20_000), faults=flags))
    assert fan.watchdog_holds == 2
