"""Request/ACK bookkeeping: which sent message an ACK or NACK answers, retries, and frame NACKs.

A :class:`RequestTable` holds, keyed by the 16-bit wire sequence number a message was sent with:

* ``pending``: the :class:`host.link.waiting.Reply` of a request awaiting its ACK (or of a camera
  capture awaiting its image); every copy of a re-sent request maps to the same reply, so the first
  ACK/NACK to any copy answers;
* ``frame_nacks``: the NACKs of messages nobody awaits (timed servo frames), the latest 1024 kept;
* ``nack_waiters``: who waits for a given frame's NACK (:meth:`wait_frame_nack`).

:meth:`RequestTable.request` is the retry loop: send, wait ``per_try`` s, send again with a new
sequence number, ``attempts`` times in all. Sequence numbers wrap: :meth:`forget_seq` drops a number's
old entries before it is sent again (an answer from one lap is never taken for the next). No I/O of
its own: the session passes its send function.
"""

from __future__ import annotations

import logging
from collections import OrderedDict
from collections.abc import Callable
from typing import Any, Protocol

import anyio

from host.link.errors import LinkError, LinkTimeout, NackError
from host.link.waiting import Reply
from protocol.messages import Ack, Message, Nack

__all__ = ["MAX_FRAME_NACKS", "AnswerSlot", "RequestTable", "RetransmitTimeout"]

log = logging.getLogger("host.link")
#: frame NACKs kept (oldest dropped)
MAX_FRAME_NACKS = 1024


class RetransmitTimeout:
    """The wait before a request is sent again, from the link's measured request -> ACK round trips.

    RFC 6298 (TCP's retransmission timer): the first sample R sets SRTT = R and RTTVAR = R/2; each
    later one RTTVAR = (1 - 1/4)·RTTVAR + 1/4·|SRTT - R|, SRTT = (1 - 1/8)·SRTT + 1/8·R; the timeout
    is SRTT + max(G, 4·RTTVAR) with clock granularity G = 1 ms, clamped to [``min_s``, ``max_s``]
    (``max_s`` before the first sample, as the RFC's initial 1 s). Samples come from answers timed
    from the copy they name (each copy has its own sequence number, so, unlike TCP's, no answer is
    ambiguous and Karn's rule is not needed; a timer that fired early is corrected by the next
    answer to a late copy). ``min_s`` is 0.1 s, not the RFC's 1 s: a board answers in ~1 ms over a
    pty or SLCAN and in tens of ms under QEMU, and a re-send that was not needed costs one duplicate
    the board applies to the same effect.
    """

    ALPHA, BETA, K, G = 1 / 8, 1 / 4, 4, 0.001

    def __init__(self, min_s: float = 0.1, max_s: float = 1.0) -> None:
        if not 0 < min_s <= max_s:
            raise ValueError(f"need 0 < min_s <= max_s, got {min_s}, {max_s}")
        self.min_s, self.max_s = min_s, max_s
        self.srtt: float | None = None
        self.rttvar = 0.0
        self.samples = 0

    def sample(self, rtt_s: float) -> None:
        """One measured round trip (s): a copy's send to the ACK/NACK that names it."""
        r = max(0.0, float(rtt_s))
        if self.srtt is None:
            self.srtt, self.rttvar = r, r / 2
        else:
            self.rttvar = (1 - self.BETA) * self.rttvar + self.BETA * abs(self.srtt - r)
            self.srtt = (1 - self.ALPHA) * self.srtt + self.ALPHA * r
        self.samples += 1

    def timeout_s(self) -> float:
        """The wait (s) before the first re-send of the next request."""
        if self.srtt is None:
            return self.max_s
        return min(self.max_s, max(self.min_s, self.srtt + max(self.G, self.K * self.rttvar)))


class AnswerSlot(Protocol):
    """What the receive path needs of a pending answer (a :class:`Reply`; an :class:`asyncio.Future` fits too)."""

    def done(self) -> bool: ...
    def set_result(self, value: Any, /) -> None: ...
    def set_exception(self, exc: BaseException, /) -> None: ...
    def exception(self) -> BaseException | None: ...


class RequestTable:
    """Pending requests, frame NACKs and NACK waiters by wire sequence number (module docstring)."""

    def __init__(self, on_retry: Callable[[], None] = lambda: None) -> None:
        #: called once per re-sent request (the session counts them in ``stats.retries``)
        self.on_retry = on_retry
        self.pending: dict[int, AnswerSlot] = {}
        self.frame_nacks: OrderedDict[int, Nack] = OrderedDict()
        self.nack_waiters: list[tuple[int, Reply[Nack | None]]] = []

    # --- answers (called by the session's receive path) -------------------------------------

    def on_ack(self, msg: Ack) -> None:
        """An ACK: it answers the request sent with ``msg.ack_seq``, if one waits."""
        fut = self.pending.get(msg.ack_seq)
        if fut is not None and not fut.done():
            fut.set_result(msg)

    def on_result(self, seq: int, value: object) -> None:
        """Answer the request sent with ``seq`` with ``value`` (a camera image)."""
        fut = self.pending.get(seq)
        if fut is not None and not fut.done():
            fut.set_result(value)

    def on_nack(self, msg: Nack) -> bool:
        """A NACK: fail the request it answers (True), else record it as a frame NACK, wake its
        waiters and return False (the caller counts it and calls its ``on_nack`` listeners)."""
        fut = self.pending.get(msg.ack_seq)
        if fut is not None and not fut.done():
            fut.set_exception(NackError(msg))
            return True
        self.frame_nacks[msg.ack_seq] = msg
        while len(self.frame_nacks) > MAX_FRAME_NACKS:
            self.frame_nacks.popitem(last=False)
        log.debug("link: %s", NackError(msg))
        self._answer_waiters(msg.ack_seq, msg)
        return False

    def _answer_waiters(self, seq: int, value: Nack | None) -> None:
        if not self.nack_waiters:
            return
        for s, w in self.nack_waiters:
            if s == seq and not w.done():
                w.set_result(value)
        self.nack_waiters = [(s, w) for s, w in self.nack_waiters if not w.done()]

    @staticmethod
    def _sample(rto: RetransmitTimeout, reply: Reply[Ack], sent_at: dict[int, float]) -> None:
        """A round-trip sample from the copy the board answered: every copy has its own sequence
        number and the ACK (or NACK) names it, so no answer is ambiguous (what Karn's rule guards
        against in TCP). A request ended by the link going down is no sample."""
        try:
            answer: Ack | Nack = reply.result()
        except NackError as e:
            answer = e.nack
        except Exception:
            return
        t = sent_at.get(answer.ack_seq & 0xFFFF)
        if t is not None:
            rto.sample(anyio.current_time() - t)

    # --- sequence numbers and link loss ------------------------------------------------------

    def forget_seq(self, seq: int) -> None:
        """``seq`` is about to be reused (16-bit wrap): drop everything keyed by its previous use.

        An old NACK no longer describes the frame that will carry ``seq``; a waiter for the old
        frame's NACK gets None (no NACK came in a whole lap); a request still awaiting the old
        ACK fails, since an ACK from now on would be for the new message.
        """
        self.frame_nacks.pop(seq, None)
        self._answer_waiters(seq, None)
        old = self.pending.pop(seq, None)
        if old is not None and not old.done():
            old.set_exception(LinkTimeout(f"no reply for seq {seq} before the sequence number came round again"))
            old.exception()

    def fail_all(self, exc: LinkError) -> None:
        """The link went down: every pending request and NACK waiter fails with ``exc``."""
        for fut in [*self.pending.values(), *(w for _, w in self.nack_waiters)]:
            if not fut.done():
                fut.set_exception(exc)
                fut.exception()  # mark retrieved: nobody may be awaiting it
        self.pending.clear()
        self.nack_waiters.clear()

    # --- waiting -----------------------------------------------------------------------------

    def frame_nack(self, seq: int) -> Nack | None:
        """The NACK for the latest frame sent with sequence ``seq``, if any (last 1024 kept)."""
        return self.frame_nacks.get(seq & 0xFFFF)

    async def wait_frame_nack(self, seq: int, timeout: float) -> Nack | None:
        """The NACK for frame ``seq``, waiting up to ``timeout`` s; None if none came (or ``seq`` was reused)."""
        seq &= 0xFFFF
        if seq in self.frame_nacks:
            return self.frame_nacks[seq]
        w: Reply[Nack | None] = Reply()
        self.nack_waiters.append((seq, w))
        try:
            return await w.get(timeout)
        except TimeoutError:
            return None
        finally:
            self.nack_waiters = [(s, f) for s, f in self.nack_waiters if f is not w]

    def expect(self, seq: int, reply: AnswerSlot) -> None:
        """``reply`` answers the message sent with ``seq`` (another copy of a request maps to the same)."""
        self.pending[seq] = reply

    def release(self, seqs: list[int], reply: AnswerSlot) -> None:
        """A request ended: drop its entries (those not already taken over by a reuse of the number)."""
        for seq in seqs:
            if self.pending.get(seq) is reply:
                del self.pending[seq]

    async def request(self, send: Callable[[Message], int], msg: Message, per_try: float, attempts: int,
                      rto: RetransmitTimeout | None = None) -> Ack:
        """Send ``msg`` with ``send`` and await its ACK, re-sending it (new sequence number) after
        each ``per_try`` s without a reply, ``attempts`` times in all; the first ACK/NACK to any copy
        answers. Raises :class:`NackError`, :class:`LinkTimeout`, or what ``send`` raises.

        With ``rto`` (the link's :class:`RetransmitTimeout`) the first wait is ``rto.timeout_s()``
        (at most ``per_try``), each later one twice the one before up to ``per_try`` (RFC 6298's
        back-off), and copies go out until ``attempts × per_try`` s have passed: the same patience,
        with a lost frame costing about one round-trip timeout instead of ``per_try``. Every answer is
        a round-trip sample for ``rto``, timed from the copy it names (:meth:`_sample`)."""
        reply: Reply[Ack] = Reply()
        n = max(1, attempts)
        seqs: list[int] = []
        sent_at: dict[int, float] = {}  # each copy's send time, by its sequence number
        budget = n * per_try
        start = anyio.current_time()
        wait = per_try if rto is None else min(per_try, rto.timeout_s())
        try:
            while True:
                t_send = anyio.current_time()
                seq = send(msg)
                seqs.append(seq)
                sent_at[seq & 0xFFFF] = t_send
                self.expect(seq, reply)
                if await reply.wait(wait):
                    if rto is not None:
                        self._sample(rto, reply, sent_at)
                    return reply.result()
                left = budget - (anyio.current_time() - start)
                if len(seqs) >= n and (rto is None or left < rto.min_s):
                    break
                if rto is not None:
                    wait = min(per_try, 2 * wait)
                    if len(seqs) >= n:  # the attempts are used up: the rest of the patience only
                        wait = min(wait, left)
                self.on_retry()
            tries = (f"{n} attempt(s) of {per_try} s" if rto is None
                     else f"{len(seqs)} attempt(s) in {anyio.current_time() - start:.2f} s")
            raise LinkTimeout(f"no ACK for {type(msg).__name__} (seq {', '.join(map(str, seqs))}) after {tries}")
        finally:
            reply.cancel()
            self.release(seqs, reply)
