"""The board fuzz target also runs ticks the way the lockstep server does (``Board.run``: quiet
stretches in one native call), after a TICKS op with n >= 128, and checks what a batch did.

Inputs are written in the target's layout (firmware_sim/fuzz.py): SERVO frames, then TICKS.
"""

from __future__ import annotations

import struct

import pytest

import firmware_sim.board as board_module
from firmware_sim.fuzz import load


def _servo(seq: int, dt_100us: int, mask: int, targets: list[int]) -> bytes:
    return struct.pack("<BHhH", 1, seq, dt_100us, mask) + b"".join(struct.pack("<h", t) for t in targets)


def _ticks(n: int) -> bytes:
    return struct.pack("<BB", 2, n)


def _input(batched: bool) -> bytes:
    frames = b"".join(_servo(i, 20 * (i + 1), 0b11, [300 * (i + 1), -300 * (i + 1)]) for i in range(4))
    return frames + _ticks((0x80 if batched else 0) | 40)


@pytest.mark.parametrize("batched", [False, True])
def test_ticks_run_through_board_run_only_when_asked(batched: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    one_input = load()
    calls: list[int] = []
    run = board_module.Board.run

    def counting_run(self: board_module.Board, max_ticks: int) -> tuple[int, list]:
        n, out = run(self, max_ticks)
        calls.append(n)
        return n, out

    monkeypatch.setattr(board_module.Board, "run", counting_run)
    one_input(_input(batched))
    if batched:
        assert calls and sum(calls) > len(calls)  # some batch ran more than one tick at once
    else:
        assert not calls


def test_a_batch_that_breaks_the_speed_limit_is_caught(monkeypatch: pytest.MonkeyPatch) -> None:
    """The batch check can fail: a board whose run moved a servo further than its speed allows."""
    one_input = load()
    run = board_module.Board.run

    def jumping_run(self: board_module.Board, max_ticks: int) -> tuple[int, list]:
        n, out = run(self, max_ticks)
        cmd, lo, hi = self.servo._cmd, self.servo.mins[0], self.servo.maxs[0]
        cmd[0] = lo if cmd[0] - lo > hi - cmd[0] else hi  # the far joint limit: inside the limits, too far for n ticks
        return n, out

    monkeypatch.setattr(board_module.Board, "run", jumping_run)
    with pytest.raises(AssertionError, match="speed limit broken"):
        one_input(_input(batched=True))


@pytest.mark.parametrize("broken, message", [
    ("speed", r"speed limit broken over 1 tick\(s\) \(the input's tick or batch 3 of "),
    ("cmd", r"command outside joint limits \(the input's tick or batch 3 of "),
    ("ctrl", r"ctrl outside joint limits \(the input's tick or batch 3 of "),
])
def test_a_single_tick_that_breaks_a_limit_is_caught(broken: str, message: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """The per-tick limits are checked at the input's end, over every tick at once: a tick that broke
    one, anywhere in the input, still fails it and is named (not only the last tick)."""
    one_input = load()
    tick = board_module.Board.tick
    ticks = [0]

    def bad_tick(self: board_module.Board) -> list:
        out = tick(self)
        ticks[0] += 1
        if ticks[0] == 3:  # an early tick: later ticks run on from where it left the servo
            lo, hi = self.servo.mins[0], self.servo.maxs[0]
            if broken == "speed":
                self.servo._cmd[0] = lo if self.servo._cmd[0] - lo > hi - self.servo._cmd[0] else hi
            elif broken == "cmd":
                self.servo._cmd[0] = hi + 0.1
            else:
                self._ctrl[0] = lo - 0.1
        return out

    monkeypatch.setattr(board_module.Board, "tick", bad_tick)
    with pytest.raises(AssertionError, match=message):
        one_input(_input(batched=False))
    assert ticks[0] > 3
