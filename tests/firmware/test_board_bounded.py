"""A long-lived board keeps bounded state: more rounds of every kind of message, no more memory.

A board process serves one link for hours, so whatever the board keeps per message, per tick or
per event must be capped (jitter buffer, screen/speaker histories and schedules, watchdog events,
renderers, capture map). One round sends every kind of host message the core handles, 300 screen
and speaker commands (more than the 256-entry histories), servo frames, FLUSH, ten ESTOP/clear
cycles and a watchdog hold, crouch and clear. The deep size of the board's Python state (every
object reachable from it, MuJoCo's fixed buffers aside) after two warm-up rounds and after four
more must agree to within ``SLACK``: a container that grows by one entry per ESTOP or per watchdog
trip would add about 6 KB. Deterministic: lockstep, no clock, no tracemalloc.
"""

from __future__ import annotations

import gc
import sys
import types

import mujoco
import numpy as np

from firmware_sim.board import Board
from protocol.messages import (
    Advance,
    Config,
    ConfigKey,
    Estop,
    EstopClear,
    Flush,
    Heartbeat,
    ScreenCommand,
    ScreenTarget,
    ServoFrame,
    SoundKind,
    SpeakerAction,
    SpeakerCommand,
    TimeSyncRequest,
)
from robots.coco import load_servo_table

from .conftest import make_board, run

NEUTRAL = load_servo_table().neutral
SLACK = 1024  # bytes: the current state (buffered frames, schedules, ints) varies a little between rounds


def deep_size(root: object) -> int:
    """Bytes of every object reachable from ``root``, not counting code, classes, modules and MuJoCo."""
    skip = (type, types.ModuleType, types.FunctionType, types.BuiltinFunctionType, types.CodeType,
            mujoco.MjModel, mujoco.MjData)
    seen: set[int] = set()
    todo, total = [root], 0
    while todo:
        obj = todo.pop()
        if id(obj) in seen or isinstance(obj, skip):
            continue
        seen.add(id(obj))
        total += sys.getsizeof(obj)
        if isinstance(obj, np.ndarray) and obj.base is not None:
            continue  # a view into MuJoCo's buffers
        todo.extend(gc.get_referents(obj))
    return total


def one_round(b: Board, k: int) -> None:
    """Every kind of host message, many times, on board time that keeps running."""
    t0 = b.now_us
    for i in range(300):
        b.handle(ScreenCommand(ScreenTarget(i % 3), f"face{i % 7}", t0 + i * 1_000, 500), i)
        b.handle(SpeakerCommand(SpeakerAction.PLAY, SoundKind.SPEECH, t0 + i * 1_000, 400, 80, "", f"say {i % 5}"), i)
    for j in range(1, 21):  # 0.4 s of servo frames, a FLUSH in the middle
        q = [v + 0.1 * np.sin(j + k) for v in NEUTRAL]
        b.handle(ServoFrame(t0 + j * 20_000, 0x0FFF, tuple(q)), j)
    b.handle(Flush(t0 + 300_000, 0x0F0), 21)
    b.handle(TimeSyncRequest(123), 22)
    b.handle(Heartbeat(0), 23)
    b.handle(Config(ConfigKey.TELEMETRY_RATE_HZ, 50), 24)
    run(b)
    for j in range(10):  # ESTOP and clear, each held for a few ticks
        b.handle(Estop(), 30 + j)
        b.handle(Advance(b.now_us + 10_000), 40 + j)
        run(b)
        b.handle(EstopClear(), 50 + j)
    b.handle(Advance(b.now_us + 1_500_000), 60)  # silence: watchdog hold, then crouch, fault latched
    run(b)
    b.handle(EstopClear(), 61)


def test_long_lived_board_state_stays_bounded() -> None:
    b = make_board()
    for k in range(2):  # warm-up: the capped containers fill (watchdog events reach their 16)
        one_round(b, k)
    gc.collect()
    warm = deep_size(b)
    for k in range(2, 6):
        one_round(b, k)
    gc.collect()
    grown = deep_size(b) - warm
    assert grown < SLACK, f"board state grew {grown} B over four more rounds"
    assert len(b.screen.history) == 256 and len(b.speaker.history) == 256  # the rounds did fill the histories
