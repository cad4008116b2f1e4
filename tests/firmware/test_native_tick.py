"""The native tick (firmware_sim/native/tick.c) is bit-identical to the Python reference path.

Two lockstep boards, one per path, get the same long random stream (frames on and off the grid, partial
masks, targets past the joint and speed limits, late and far-future frames, FLUSH, ESTOP / ESTOP_CLEAR,
silences that trip the watchdog into HOLD and CROUCH and the blend back, CONFIG changes, pushes on the
base, a robot with substeps). After every tick their whole state must agree to the bit: MuJoCo's qpos,
qvel, act, ctrl and warm-start, the servo commands, the interpolated targets, the anchors, every reply
and report, the counters.
"""

from __future__ import annotations

import random
from pathlib import Path

import numpy as np
import pytest

from firmware_sim.board import Board
from firmware_sim.config import BoardConfig
from firmware_sim.native import NativeUnavailable, native_reason
from protocol.messages import (
    PROTOCOL_VERSION,
    Advance,
    Config,
    ConfigKey,
    Estop,
    EstopClear,
    Flush,
    Hello,
    Message,
    ServoFrame,
)
from support.gen_robot import write_chain_robot


def _state(b: Board) -> bytes:
    d = b.data
    parts = [d.qpos, d.qvel, d.act, d.ctrl, d.qacc_warmstart, d.xfrc_applied, b.servo._cmd, b._desired, b._ctrl,
             b.anchor_t, b.anchor_v, np.array([d.time])]
    counters = (b.now_us, b.ticks, b.last_applied_seq, b.late_count, b.dropped_count, b.clamped_ticks,
                b.servo.limit_clamps, b.servo.speed_clamps, b.mode.value, len(b.buffer), b.stream.blending)
    return b"".join(np.ascontiguousarray(p).tobytes() for p in parts) + repr(counters).encode()


class _Stream:
    """A reproducible random host: messages with the board time they are sent at."""

    def __init__(self, seed: int, n: int, neutral: list[float], span: float) -> None:
        self.rng = random.Random(seed)
        self.n, self.neutral, self.span = n, neutral, span
        self.seq = 0

    def _targets(self, mask: int) -> tuple[float, ...]:
        r = self.rng
        wild = r.random() < 0.1  # past the joint limits and the speed limit
        return tuple(self.neutral[i] + r.uniform(-1, 1) * (3.0 if wild else self.span)
                     for i in range(self.n) if mask >> i & 1)

    def next(self, now_us: int) -> tuple[Message, int] | tuple[str, object]:
        r = self.rng
        self.seq += 1
        x = r.random()
        full = (1 << self.n) - 1
        if x < 0.80:
            mask = full if r.random() < 0.7 else (r.getrandbits(self.n) or 1)
            if r.random() < 0.8:
                t = (now_us // 10_000 + r.randint(1, 8)) * 10_000  # on the grid, ahead
            else:
                t = now_us + r.randint(-30_000, 200_000)  # off the grid, some late
            return ServoFrame(max(0, t), mask, self._targets(mask)), self.seq
        if x < 0.84:
            return Flush(now_us + r.randint(0, 60_000), r.getrandbits(self.n) or full), self.seq
        if x < 0.86:
            return Estop(), self.seq
        if x < 0.90:
            return EstopClear(), self.seq
        if x < 0.94:  # silence: the board runs on its own (HOLD after the watchdog, CROUCH later)
            return Advance(now_us + r.choice([40_000, 300_000, 1_500_000])), self.seq
        if x < 0.97:
            key = r.choice([ConfigKey.WATCHDOG_MS, ConfigKey.CROUCH_AFTER_MS, ConfigKey.TELEMETRY_RATE_HZ])
            return Config(key, r.choice([5, 25, 100, 400])), self.seq
        return "push", (now_us / 1e6 + r.uniform(0, 0.3), (r.uniform(-20, 20), r.uniform(-20, 20), 0.0),
                        r.uniform(0.01, 0.2))


def _run_pair(cfg: dict[str, object], seed: int, ticks: int, robot: str | None = None) -> int:
    boards = [Board(BoardConfig(lockstep=True, kernel=k, **({"robot": robot} if robot else {}), **cfg))  # type: ignore[arg-type]
              for k in ("python", "native!")]
    py, nat = boards
    assert py.native is None and nat.native is not None
    for b in boards:
        assert b.handle(Hello(PROTOCOL_VERSION, b.wire_schema.hash, 0), 0)
    stream = _Stream(seed, py.n, list(py.table.neutral), 0.4)
    ran = 0
    while ran < ticks:
        op = stream.next(py.now_us)
        if op[0] == "push":
            push: tuple[float, tuple[float, float, float], float] = op[1]  # type: ignore[assignment]
            at, force, dur = push
            for b in boards:
                b.push(at, force, dur)
            continue
        msg, seq = op  # type: ignore[misc]
        replies = [b.handle(msg, seq) for b in boards]  # type: ignore[arg-type]
        assert replies[0] == replies[1], f"seed {seed} tick {ran}: replies differ for {msg}"
        assert _state(py) == _state(nat), f"seed {seed}: state differs after {msg}"
        while py.can_tick() and ran < ticks:
            assert nat.can_tick()
            outs = [b.tick() for b in boards]
            ran += 1
            assert outs[0] == outs[1], f"seed {seed} tick {ran}: reports differ"
            assert _state(py) == _state(nat), f"seed {seed} tick {ran} (t = {py.now_us} us): state differs"
        assert nat.can_tick() == py.can_tick()
    return ran


def _require_native() -> None:
    reason = native_reason()
    if reason is not None:
        raise NativeUnavailable(reason)  # fail, not skip: .ci/setup installs gcc


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_native_tick_is_bit_identical_to_python_on_coco(seed: int) -> None:
    _require_native()
    assert _run_pair({}, seed, 12_000) == 12_000


def test_native_tick_bit_identical_with_substeps_and_a_short_watchdog() -> None:
    _require_native()
    assert _run_pair({"rate_hz": 250, "dt": 0.002, "watchdog_ms": 30, "crouch_after_ms": 60}, 7, 4_000) == 4_000


@pytest.mark.parametrize("n", [1, 20])
def test_native_tick_bit_identical_on_other_robots(tmp_path: Path, n: int) -> None:
    _require_native()
    pkg = write_chain_robot(tmp_path, n)
    assert _run_pair({}, 10 + n, 3_000, robot=str(pkg)) == 3_000


def test_python_is_the_reference_and_native_the_default(monkeypatch: pytest.MonkeyPatch) -> None:
    _require_native()
    monkeypatch.delenv("GHOSTSHELL_BOARD_KERNEL", raising=False)
    assert Board(BoardConfig(lockstep=True)).native is not None
    monkeypatch.setenv("GHOSTSHELL_BOARD_KERNEL", "python")
    assert Board(BoardConfig(lockstep=True)).native is None
    with pytest.raises(ValueError, match="board kernel must be native, native! or python"):
        Board(BoardConfig(lockstep=True, kernel="fortran"))


def _run_batched(cfg: dict[str, object], seed: int, ticks: int, robot: str | None = None) -> tuple[int, int]:
    """The Python reference ticking one tick at a time against the native kernel through ``Board.run``
    (quiet ticks batched into one C call): after every run both boards agree to the bit, the reference's
    ticks before the run's last returned nothing, and the last returned what the run did. Returns (ticks
    run, ticks that went through a batch of more than one)."""
    boards = [Board(BoardConfig(lockstep=True, kernel=k, **({"robot": robot} if robot else {}), **cfg))  # type: ignore[arg-type]
              for k in ("python", "native!")]
    py, nat = boards
    batched = [0]
    quiet = nat._run_quiet

    def counting(limit: int) -> tuple[int, list[Message]] | None:
        got = quiet(limit)
        if got is not None and got[0] > 1:
            batched[0] += got[0]
        return got

    nat._run_quiet = counting  # type: ignore[method-assign]
    for b in boards:
        assert b.handle(Hello(PROTOCOL_VERSION, b.wire_schema.hash, 0), 0)
    stream = _Stream(seed, py.n, list(py.table.neutral), 0.4)
    rng = random.Random(seed)
    ran = 0
    full = (1 << py.n) - 1
    while ran < ticks:
        # half the time a steady host (every servo, 50 Hz on the grid, 100 ms ahead), so quiet runs occur
        if rng.random() < 0.5:
            stream.seq += 1
            op = (ServoFrame((py.now_us // 20_000 + 5) * 20_000, full, stream._targets(full)), stream.seq)
        else:
            op = stream.next(py.now_us)
        if op[0] == "push":
            at, force, dur = op[1]  # type: ignore[misc]
            for b in boards:
                b.push(at, force, dur)
            continue
        msg, seq = op  # type: ignore[misc]
        assert py.handle(msg, seq) == nat.handle(msg, seq)  # type: ignore[arg-type]
        while nat.can_tick() and ran < ticks:
            n, out = nat.run(rng.choice([1, 3, 40, 256]))
            assert n >= 1
            for k in range(n):
                assert py.can_tick()
                ref = py.tick()
                assert ref == (out if k == n - 1 else []), f"seed {seed} tick {ran + k + 1}: reports differ"
                assert (k == n - 1) or not py.watchdog_events
            ran += n
            assert list(py.watchdog_events) == list(nat.watchdog_events), f"seed {seed} tick {ran}"
            py.watchdog_events.clear()
            nat.watchdog_events.clear()
            assert _state(py) == _state(nat), f"seed {seed} tick {ran} (t = {py.now_us} us): state differs"
        assert nat.can_tick() == py.can_tick()
    return ran, batched[0]


@pytest.mark.parametrize("seed", [4, 5])
def test_batched_native_ticks_are_the_reference_tick_by_tick(seed: int) -> None:
    _require_native()
    ran, batched = _run_batched({}, seed, 12_000)
    assert ran >= 12_000 and batched > 50  # the stream's quiet stretches went through batches


def test_batched_ticks_with_substeps_a_short_watchdog_and_other_robots(tmp_path: Path) -> None:
    _require_native()
    ran, batched = _run_batched({"rate_hz": 250, "dt": 0.002, "watchdog_ms": 30, "crouch_after_ms": 60}, 8, 4_000)
    assert ran >= 4_000 and batched > 0
    ran, batched = _run_batched({}, 21, 3_000, robot=str(write_chain_robot(tmp_path, 20)))
    assert ran >= 3_000 and batched > 0


def test_a_quiet_stream_runs_a_report_period_per_call() -> None:
    """Frames every 20 ms, telemetry every 10 ticks: the ticks between reports run as one C call."""
    _require_native()
    b = Board(BoardConfig(lockstep=True, kernel="native!"))
    b.handle(Hello(PROTOCOL_VERSION, b.wire_schema.hash, 0), 0)
    neutral = tuple(b.table.neutral)
    for k in range(1, 51):
        assert b.handle(ServoFrame(k * 20_000, b.table.all_mask, neutral), k) == []
    runs = []
    while b.can_tick():
        n, out = b.run(256)
        runs.append((n, [type(m).__name__ for m in out]))
    assert sum(n for n, _ in runs) == 501 and b.now_us == 1_002_000
    # ticks 0..9 (a report after tick 9), then each frame's tick and the 9 after it (no frame due there)
    assert all(r == (10, ["Telemetry", "SimState"]) for r in runs[:-1]) and runs[-1] == (1, [])
    assert b.last_applied_seq == 50


def test_mujoco_timers_are_off_with_the_native_kernel_unless_asked() -> None:
    """MuJoCo's stage timers cost ~1 µs per step; a process that loads the C tick stops them
    (GHOSTSHELL_MJ_TIMERS=1 keeps them), and the physics is the same bit for bit either way."""
    _require_native()
    import os
    import subprocess
    import sys

    code = ("from firmware_sim.board import Board; from firmware_sim.config import BoardConfig\n"
            "b = Board(BoardConfig(lockstep=True, kernel='native!')); b.advance_until = 400_000\n"
            "while b.can_tick(): b.run(256)\n"
            "import hashlib; print(b.data.timer[0].number, b.data.timer[0].duration > 0,"
            " hashlib.sha256(b.data.qpos.tobytes() + b.data.qvel.tobytes()).hexdigest())")
    got = {}
    for keep in ("0", "1"):
        env = dict(os.environ, GHOSTSHELL_MJ_TIMERS=keep)
        r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120,
                           cwd=Path(__file__).resolve().parents[2])
        assert r.returncode == 0, r.stderr
        got[keep] = r.stdout.split()
    assert got["0"][:2] == ["200", "False"] and got["1"][:2] == ["200", "True"]
    assert got["0"][2] == got["1"][2]
