"""Fuzz target ``board``: assembled host messages with fuzzed fields and order into the lockstep board core.

Like MAVLink's fuzz harnesses, the fuzzer does not spend its effort on CRCs: the input is a stream of
*operations* whose fields are fuzzed, and every message is framed with a valid CRC
(``protocol.framing``), decoded again and handed to :meth:`firmware_sim.board.Board.handle`, exactly
as the serial server does. Ticks run in lockstep as ``firmware_sim.server`` runs them: before each message the board ticks while
:meth:`Board.can_tick` (frames or an ADVANCE cover the time), at most :data:`TICKS_PER_INPUT` (40 ticks,
80 ms) per input. The process builds its MuJoCo model and ``MjData`` once; each input's board reuses them.

Input layout (little-endian; a short read ends the input)::

    op u8 (mod 8), then
    0 RAW      type u8, seq u16, len u8, payload[len]   any message type, fuzzed payload bytes
    1 SERVO    seq u16, dt i16 (x 100 us from board now), mask u16, popcount(mask) x i16 (x 1e-4 rad)
    2 TICKS    n u8                                      ADVANCE by n mod 128 ticks; n >= 128: the
                                                         ticks it covers run batched (Board.run)
    3 FLUSH    seq u16, dt i16 (x 100 us), mask u16
    4 ESTOP    seq u16
    5 CLEAR    seq u16                                    ESTOP_CLEAR
    6 CONFIG   seq u16, key u8, value u32
    7 QUIET    n u8                                      (n mod 16) x ADVANCE by 8 ticks (watchdog)

A hand-written reader (not atheris' ``FuzzedDataProvider``, which takes integers from the end of the
input) keeps the layout simple enough to write seeds from frame logs (``host.tools.fuzz.seeds``).

Invariants (an ``AssertionError`` names the one that broke):

* ``handle`` and ``tick`` never raise;
* every tick's servo command stays inside the joint limits, and moves at most one tick's worth of
  the servo's speed limit (ESTOP and resume re-anchor outside the tick, which is allowed);
* every applied frame is byte-for-byte one that was accepted, was inside its window
  ``[now - max_late, now + max_future]`` when accepted, and is applied no earlier than its time;
* the jitter buffer never exceeds its capacity;
* ESTOP always wins: from its ACK until ESTOP_CLEAR every SERVO_FRAME is refused, nothing is
  applied, the buffer stays empty and every tick holds the e-stop pose.

Ticks run one by one (:meth:`Board.tick`), as a realtime board's pacer runs them, except after a
TICKS op with n >= 128: those run through :meth:`Board.run`, as the lockstep server runs them (quiet
stretches in one native call). A batch is checked at its end: the same limits, a step of at most
the ticks' worth of speed, the applied frames, ESTOP's pose and the buffer's bound.

Throughput (measured exec/s, with command, n and load: docs/guides/fuzzing.md#throughput): the process compiles the
model and allocates ``MjData`` once (each input's fresh board reuses them and the loaded robot); an
input runs at most :data:`TICKS_PER_INPUT` ticks; coverage instruments only the board core
(:data:`UNDER_TEST`). Every invariant is checked on every tick of every input; the joint and speed
limits of all of an input's ticks in one NumPy pass at its end (each tick keeps its command before and
after and its ctrl in a row; per tick the NumPy calls cost 13 % of an input), which names the first
tick that broke one. Nothing is remembered
from input to input (``tests/fuzz/test_fuzz_memory.py``): an input's frames carry board times, so a
decode cache as the serial-decoder target's would mostly grow.

This module carries its own three-line atheris runner because the board never imports the host.
"""

from __future__ import annotations

import importlib.util
import pkgutil
import struct
import sys
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager

__all__ = ["load", "Reader", "TICKS_PER_INPUT"]

#: ticks one input may run (80 ms of board time at 500 Hz): ticks (a MuJoCo step, the board's own
#: work and this target's checks each) are the largest part of an input's time, so this bounds it. It still covers the fuzz config's watchdog: HOLD after 20 ms without a
#: valid message (tick 11), CROUCH 40 ms later (tick 31). It was 400 (0.8 s).
TICKS_PER_INPUT = 40


_STRUCTS = {f: struct.Struct("<" + f) for f in "BHhI"}


class Reader:
    """Little-endian field reader over the fuzz input; :class:`EOFError` when it runs out."""

    def __init__(self, data: bytes) -> None:
        self.data = data
        self.i = 0

    def take(self, fmt: str) -> int:
        s = _STRUCTS[fmt]
        if self.i + s.size > len(self.data):
            raise EOFError
        (v,) = s.unpack_from(self.data, self.i)
        self.i += s.size
        return int(v)

    def raw(self, n: int) -> bytes:
        out = self.data[self.i : self.i + n]
        self.i += len(out)
        return out


#: the board core this target instruments (not protocol's codecs: the serial-decoder target's; not
#: the native tick's ctypes wrapper, the robot loader or the transports)
UNDER_TEST = ("firmware_sim.board", "firmware_sim.config", "firmware_sim.jitter_buffer", "firmware_sim.peripherals",
              "firmware_sim.safety", "firmware_sim.servo_model")


@contextmanager
def _instrument_only(modules: Sequence[str]) -> Iterator[None]:
    """A copy of ``host.tools.fuzz.harness.instrument_only`` (the board never imports the host): atheris'
    ``include`` takes top-level packages only, so every other module of the package is excluded."""
    import atheris  # type: ignore[import-not-found,unused-ignore]

    tops = sorted({m.split(".")[0] for m in modules})
    names: list[str] = []
    for top in tops:
        spec = importlib.util.find_spec(top)
        names.append(top)
        stack = [(top, list(spec.submodule_search_locations or []))] if spec else []
        while stack:
            prefix, paths = stack.pop()
            for info in pkgutil.iter_modules(paths):
                names.append(f"{prefix}.{info.name}")
                if info.ispkg:
                    stack.append((f"{prefix}.{info.name}", [f"{p}/{info.name}" for p in paths]))
    others = [n for n in names if not any(n == m or n.startswith(m + ".") for m in modules)]
    with atheris.instrument_imports(include=tops, exclude=others):
        yield


def load(instrument: bool = False, *, persistent: bool = False) -> Callable[[bytes], None]:
    """Import the board (instrumented when ``instrument``) and return the one-input function.

    Each input runs on a fresh board (built on the process's one compiled model and ``MjData``,
    see :class:`firmware_sim.board.Board`'s ``reuse``). ``persistent``: every input runs on one
    long-lived board and frame decoder instead, as a board process serves one link for hours; each
    input then starts with a FLUSH of every servo (so the frames it checks are its own). Used by the
    memory test (tests/fuzz/test_fuzz_memory.py): whatever a board keeps must stay bounded.
    """
    if instrument:
        with _instrument_only(UNDER_TEST):
            import firmware_sim.board  # noqa: F401
    import numpy as np

    from firmware_sim.board import Board
    from firmware_sim.config import BoardConfig
    from firmware_sim.jitter_buffer import BufferedFrame
    from firmware_sim.safety import Mode
    from protocol.codec import quantize_apply_at, unwrap_time_us
    from protocol.framing import Frame, FrameDecoder, encode_frame, encode_raw_frame
    from protocol.messages import (
        Ack, Advance, Config, ConfigKey, Estop, EstopClear, Flush, Message, MsgType, Nack, NackReason, ServoFrame,
    )

    def config() -> BoardConfig:
        return BoardConfig(lockstep=True, buffer_depth=16, watchdog_ms=20, crouch_after_ms=40)

    # (seq, apply_at) -> every (board time at acceptance, targets) accepted under that key
    Accepted = dict[tuple[int, int], list[tuple[int, dict[int, float]]]]
    # the last board (its model and MjData go to the next input's board) and, when persistent, its
    # decoder and bookkeeping: a new 14 MB MuJoCo arena per input fragments the C heap (RSS creeps)
    last: list[tuple[Board, FrameDecoder, Accepted, list[BufferedFrame]]] = []

    def observe_pops(board: Board, applied: list[BufferedFrame]) -> None:
        """Every frame the tick takes from the jitter buffer is appended to ``applied``."""
        pop_due = board.buffer.pop_due

        def observed_pop(t: int) -> list[BufferedFrame]:
            due = pop_due(t)
            applied.extend(due)
            return due

        board.buffer.pop_due = observed_pop  # type: ignore[method-assign,assignment]

    # one row per checked step of an input (at most TICKS_PER_INPUT), by servo count; reused by every input
    rows: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def one_input(data: bytes) -> None:
        if persistent and last:
            board, dec, accepted, applied = last[0]
        else:
            prev = last[0][0] if last else None
            board = Board(config(), reuse=prev, robot=prev.robot if prev else None)  # the robot found once
            dec, accepted, applied = FrameDecoder(schema=board.wire_schema), {}, []
            observe_pops(board, applied)
            last[:] = [(board, dec, accepted, applied)]
        r = Reader(data)
        if board.n not in rows:
            rows[board.n] = (np.empty((TICKS_PER_INPUT, board.n)), np.empty((TICKS_PER_INPUT, board.n)),
                             np.empty((TICKS_PER_INPUT, board.n)))
        rows_before, rows_cmd, rows_ctrl = rows[board.n]
        period = board.servo.period_s
        lo, hi = board.servo.mins - 1e-9, board.servo.maxs + 1e-9
        max_step = board.servo.max_speeds * period + 1e-9
        budget = [TICKS_PER_INPUT]  # so one input cannot run for long

        batched = [False]  # after a TICKS op with n >= 128 until the next message: Board.run

        def drain() -> None:
            """Lockstep as the server runs it: the next message is handled only when no tick may run."""
            while budget[0] > 0 and board.can_tick():
                if batched[0]:
                    run_batch()
                else:
                    budget[0] -= 1
                    tick()

        def deliver(wire: bytes) -> list[Message]:
            replies: list[Message] = []
            for item in dec.feed(wire):
                drain()
                if isinstance(item, Frame) and isinstance(item.msg, ServoFrame):
                    replies += servo_frame(item.msg, item.seq)
                elif isinstance(item, Frame):
                    replies += board.handle(item.msg, item.seq)
                else:
                    board.on_link_error()
            return replies

        def servo_frame(msg: ServoFrame, seq: int) -> list[Message]:
            now, mask = board.now_us, msg.mask
            estopped, latched = board.safety.estopped, board.safety.fault_latched
            replies = board.handle(msg, seq)
            ok = mask and not mask & ~board.table.all_mask
            if not replies:
                assert ok and not estopped and not latched, f"frame accepted: mask {mask:#x}, estop {estopped}"
                # the wire carries apply-at modulo 2**32: a RAW frame's 0xFFFFFFFF at board time 0 is 1 us late
                t = unwrap_time_us(quantize_apply_at(int(msg.apply_at_us)), now)
                assert now - board.cfg.max_late_us <= t <= now + board.cfg.max_future_us, f"frame due {t} accepted at {now}"
                idx = idx_of(mask)
                accepted.setdefault((seq, t), []).append((now, dict(zip(idx, msg.targets))))
            else:
                assert len(replies) == 1 and isinstance(replies[0], Nack), f"SERVO_FRAME replies {replies}"
                if estopped and ok and len(msg.targets) == len(idx_of(mask)):
                    assert replies[0].reason is NackReason.ESTOPPED, f"ESTOP did not win: {replies[0]}"
            return replies

        def idx_of(mask: int) -> list[int]:
            return [i for i in range(board.wire_schema.max_servos) if mask >> i & 1]

        def send(msg: Message, seq: int) -> list[Message]:
            return deliver(encode_frame(msg, seq, board.wire_schema))

        # per checked step (a tick, or a batch of ticks): the command before it, the command and ctrl
        # after it, and how many ticks it ran; the limits are checked on all rows at once (limits_ok)
        ticks_of: list[int] = []

        def record(n: int) -> None:
            k = len(ticks_of)
            rows_cmd[k] = board.servo.cmd
            rows_ctrl[k] = board.ctrl
            ticks_of.append(n)

        def tick() -> None:
            """One tick, as a realtime board's pacer runs it; checked after it."""
            estopped, mode_before = board.safety.estopped, board.mode
            rows_before[len(ticks_of)] = board.servo.cmd
            applied.clear()
            board.tick()
            record(1)
            check(estopped, mode_before)

        def run_batch() -> None:
            """What :meth:`Board.run` ran, checked at its end (a batch has no tick in between to check)."""
            estopped, mode_before = board.safety.estopped, board.mode
            rows_before[len(ticks_of)] = board.servo.cmd
            applied.clear()
            n, _ = board.run(budget[0])
            assert 1 <= n <= budget[0], f"Board.run ran {n} ticks of {budget[0]}"
            budget[0] -= n
            record(n)
            check(estopped, mode_before)

        def limits_ok() -> None:
            """Joint and speed limits over every step of the input, in one NumPy pass (the input's end;
            per tick, the NumPy calls cost more than comparing 12 floats): the first step that broke
            one is named."""
            k = len(ticks_of)
            if not k:
                return
            cmd, ctrl, before = rows_cmd[:k], rows_ctrl[:k], rows_before[:k]
            step = np.abs(cmd - before)
            bound = np.asarray(ticks_of, dtype=np.float64)[:, None] * max_step
            bad = ((cmd < lo) | (cmd > hi) | (ctrl < lo) | (ctrl > hi) | (step > bound)).any(axis=1)
            if bad.any():
                i = int(np.argmax(bad))
                at = f"(the input's tick or batch {i + 1} of {k})"
                assert not ((cmd[i] < lo).any() or (cmd[i] > hi).any()), f"command outside joint limits {at}: {cmd[i]}"
                assert not ((ctrl[i] < lo).any() or (ctrl[i] > hi).any()), f"ctrl outside joint limits {at}: {ctrl[i]}"
                raise AssertionError(f"speed limit broken over {ticks_of[i]} tick(s) {at}: step {step[i]}")

        def check(estopped: bool, mode_before: Mode) -> None:
            """The invariants after a tick or batch (joint and speed limits: :func:`limits_ok`)."""
            if applied:
                t = board.now_us - board.tick_us
                for f in applied:
                    key = (f.seq, f.apply_at_us)
                    assert key in accepted, f"applied a frame never accepted: seq {f.seq} at {f.apply_at_us}"
                    # FLUSH may have removed some servos of a frame: what is applied is a subset of what was sent
                    assert any(
                        f.values == {i: v for i, v in values.items() if i in f.values} for _, values in accepted[key]
                    ), f"applied targets {f.values} differ from every frame sent as seq {f.seq}"
                    assert f.apply_at_us <= t, f"frame due {f.apply_at_us} applied early (by {t})"
            if estopped:
                assert mode_before is Mode.ESTOP and board.mode is Mode.ESTOP
                assert not applied, "a frame was applied during ESTOP"
                assert np.array_equal(board.desired, board.hold_q), "ESTOP pose not held"
            assert len(board.buffer) <= board.buffer.capacity

        def advance(n: int, batch: bool = False) -> None:
            send(Advance(board.now_us + n * board.tick_us), 0xFFFF)
            batched[0] = batch
            try:
                drain()
            finally:
                batched[0] = False

        if persistent:  # frames the previous input left in the buffer are not this input's to check
            send(Flush(0, board.table.all_mask), 0xFFFF)
            # FLUSH drops frames due at or after its time: one due before 0 (a RAW frame's apply-at
            # 0xFFFFFFFF accepted at board time 0 is due at -1) stays and is applied in this input, so
            # what was accepted for the frames still held is kept (found when the corpus changed)
            held = {(f.seq, f.apply_at_us) for f in board.buffer._frames}
            for key in [k for k in accepted if k not in held]:
                del accepted[key]
        while True:
            try:
                op = r.take("B") % 8
                if op == 0:
                    mtype, seq, n = r.take("B"), r.take("H"), r.take("B")
                    deliver(encode_raw_frame(mtype, seq, r.raw(n)))
                elif op == 1:
                    seq, dt, mask = r.take("H"), r.take("h"), r.take("H")
                    targets = tuple(r.take("h") * 1e-4 for _ in range(bin(mask).count("1")))
                    send(ServoFrame(max(0, board.now_us + dt * 100), mask, targets), seq)
                elif op == 2:
                    n = r.take("B")
                    advance(n & 0x7F, batch=n >= 0x80)
                elif op == 3:
                    seq, dt, mask = r.take("H"), r.take("h"), r.take("H")
                    send(Flush(max(0, board.now_us + dt * 100), mask), seq)
                elif op == 4:
                    replies = send(Estop(), r.take("H"))
                    assert replies and isinstance(replies[0], Ack), f"ESTOP not acknowledged: {replies}"
                    assert board.safety.estopped and len(board.buffer) == 0
                elif op == 5:
                    send(EstopClear(), r.take("H"))
                    assert not board.safety.estopped and not board.safety.fault_latched
                elif op == 6:
                    cfg_seq, cfg_key, value = r.take("H"), r.take("B"), r.take("I")
                    if cfg_key in ConfigKey._value2member_map_:
                        send(Config(ConfigKey(cfg_key), value), cfg_seq)
                else:
                    for _ in range(r.take("B") % 16):
                        advance(8)
            except EOFError:
                break
        limits_ok()
        assert dec.pending <= dec.max_frame_bytes

    return one_input


def main() -> None:
    """``python -m firmware_sim.fuzz [libFuzzer flags] [corpus dirs]``."""
    import atheris  # type: ignore[import-not-found,unused-ignore]

    # argv[0] as a command line: libFuzzer's -fork/-jobs modes re-run it through the shell
    atheris.Setup([f"{sys.executable} -m firmware_sim.fuzz", *sys.argv[1:]], load(True))
    atheris.Fuzz()


if __name__ == "__main__":
    main()
