"""host.run.turn_gc: a turn runs with the heap frozen, the heap is given back after the last turn."""

from __future__ import annotations

import gc
import threading
from collections.abc import AsyncIterator
from pathlib import Path

import anyio

from host.run.turn_gc import frozen_heap, turns_frozen
from host.run.robot_session import RobotSession, SessionOptions


def test_frozen_inside_and_given_back_after_the_last_block() -> None:
    assert turns_frozen() == 0 and gc.get_freeze_count() == 0
    with frozen_heap():
        assert gc.get_freeze_count() > 0 and turns_frozen() == 1
        with frozen_heap():  # a second session's turn in the same process
            assert turns_frozen() == 2
        assert turns_frozen() == 1 and gc.get_freeze_count() > 0  # the other turn still runs
    assert turns_frozen() == 0 and gc.get_freeze_count() == 0


def test_overlapping_turns_share_one_frozen_period() -> None:
    with frozen_heap():
        first = gc.get_freeze_count()
        made_meanwhile = [[i] for i in range(500)]
        with frozen_heap():  # only the turn that opened the period froze: no second snapshot
            assert any(o is made_meanwhile for o in gc.get_objects())
            assert gc.get_freeze_count() == first
    assert gc.get_freeze_count() == 0


def test_a_heap_frozen_for_good_before_is_left_frozen() -> None:
    gc.freeze()  # e.g. a fuzz harness after its start-up
    try:
        with frozen_heap():
            assert turns_frozen() == 1
        # not given back by the turn (gc.unfreeze would leave 0; the count itself may shrink a little:
        # frozen objects still die by reference count)
        assert gc.get_freeze_count() > 0
    finally:
        gc.unfreeze()


def test_given_back_when_the_turn_raises() -> None:
    try:
        with frozen_heap():
            raise RuntimeError("cut")
    except RuntimeError:
        pass
    assert turns_frozen() == 0 and gc.get_freeze_count() == 0


def test_threads_share_one_count() -> None:
    entered, release = threading.Barrier(3), threading.Event()

    def turn() -> None:
        with frozen_heap():
            entered.wait()
            release.wait(10)

    workers = [threading.Thread(target=turn) for _ in range(2)]
    for w in workers:
        w.start()
    entered.wait()
    assert turns_frozen() == 2 and gc.get_freeze_count() > 0
    release.set()
    for w in workers:
        w.join()
    assert turns_frozen() == 0 and gc.get_freeze_count() == 0


def test_a_session_turn_streams_with_the_heap_frozen(tmp_path: Path) -> None:
    seen: list[tuple[int, int]] = []

    async def stream() -> AsyncIterator[str]:
        for chunk in ("Hi ", '<head_act action="nod"/>', " there."):
            seen.append((turns_frozen(), gc.get_freeze_count()))
            yield chunk

    async def main() -> str:
        async with RobotSession(SessionOptions(out=tmp_path, lockstep=True)) as s:
            turn = await s.run_turn(stream(), settle_s=0.1)
            assert turns_frozen() == 0  # given back once the turn ended
            return turn.summary.outcome

    assert anyio.run(main, backend="asyncio") == "done"
    assert len(seen) == 3 and all(n == 1 and frozen > 0 for n, frozen in seen), seen
