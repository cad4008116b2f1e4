"""host.link.deferred.DeferredWork: noted calls run from the loop, in order, in slices, bounded.

Driven on a real asyncio loop; a slice of 0 s makes "one call per pass of the loop" exact, so
what else runs between two calls is deterministic (no wall-clock assumptions).
"""

from __future__ import annotations

import asyncio

import pytest

from host.link.deferred import DeferredWork


async def _passes(n: int = 20) -> None:
    for _ in range(n):
        await asyncio.sleep(0)


def test_without_a_loop_a_call_is_done_at_once() -> None:
    done: list[int] = []
    work = DeferredWork()
    work.note(done.append, 1)
    assert done == [1] and len(work) == 0


def test_from_a_loop_calls_wait_for_the_loop_and_come_in_order() -> None:
    done: list[int] = []

    async def main() -> None:
        work = DeferredWork()
        for i in range(5):
            work.note(done.append, i)
        assert done == [] and len(work) == 5  # the caller (a link callback) did none of it
        await _passes()
        assert done == [0, 1, 2, 3, 4] and len(work) == 0

    asyncio.run(main())


def test_a_slice_gives_the_loop_back_between_calls() -> None:
    """Slice 0 s: one call per pass; a callback that became ready meanwhile runs after the first call,
    not after all of them (a token chunk waited behind a whole batch before)."""
    done: list[str] = []

    async def main() -> None:
        work = DeferredWork(slice_s=0.0)
        for i in range(3):
            work.note(done.append, f"noted {i}")
        asyncio.get_running_loop().call_soon(done.append, "other")
        await _passes()
        assert done == ["noted 0", "other", "noted 1", "noted 2"]

    asyncio.run(main())


def test_a_backlog_past_max_deferred_is_done_at_once() -> None:
    """A loop that never comes round (a callback flood) must not let the noted calls grow without bound."""
    done: list[int] = []

    async def main() -> None:
        work = DeferredWork(max_deferred=3)
        work.note(done.append, 0)
        work.note(done.append, 1)
        assert done == []
        work.note(done.append, 2)  # the third: all three now, in order
        assert done == [0, 1, 2] and len(work) == 0
        await _passes()
        assert done == [0, 1, 2]  # the slice still scheduled finds nothing

    asyncio.run(main())


def test_drain_does_what_is_left_now() -> None:
    done: list[int] = []

    async def main() -> None:
        work = DeferredWork()
        work.note(done.append, 7)
        work.note(done.append, 8)
        work.drain()  # before a close: nothing may wait for a loop that is about to end
        assert done == [7, 8]
        await _passes()
        assert done == [7, 8]

    asyncio.run(main())


def test_a_failing_call_reaches_the_loop_and_the_rest_is_still_done() -> None:
    done: list[int] = []
    errors: list[BaseException] = []

    def boom() -> None:
        raise OSError("disk full")

    async def main() -> None:
        loop = asyncio.get_running_loop()
        loop.set_exception_handler(lambda _loop, ctx: errors.append(ctx["exception"]))
        work = DeferredWork()
        work.note(done.append, 1)
        work.note(boom)
        work.note(done.append, 2)
        await _passes()
        assert done == [1, 2] and len(work) == 0
        assert len(errors) == 1 and isinstance(errors[0], OSError)

    asyncio.run(main())


@pytest.mark.parametrize("slice_s", [0.0, 1.0])
def test_calls_noted_from_a_call_come_after_it(slice_s: float) -> None:
    done: list[str] = []

    async def main() -> None:
        work = DeferredWork(slice_s=slice_s)

        def first() -> None:
            done.append("first")
            work.note(done.append, "noted by first")

        work.note(first)
        work.note(done.append, "second")
        await _passes()
        assert done == ["first", "second", "noted by first"]

    asyncio.run(main())
