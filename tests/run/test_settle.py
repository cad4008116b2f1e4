"""``host.run.pump.settle``: after a lockstep report the pump yields until nothing else on the event loop
is ready (at most ``SETTLE_CHECKPOINTS`` turns), instead of always 32 turns."""

from __future__ import annotations

import asyncio

import anyio

from host.run.pump import SETTLE_CHECKPOINTS, settle


def test_a_chain_of_wake_ups_has_run_through_when_settle_returns() -> None:
    """Ten tasks each woken by the one before (an event each): all have run when ``settle`` returns,
    and it returned as soon as they had, well before its limit."""

    async def main() -> tuple[list[int], int]:
        events = [asyncio.Event() for _ in range(10)]
        reached: list[int] = []

        async def hop(i: int) -> None:
            await events[i].wait()
            reached.append(i)
            if i + 1 < len(events):
                events[i + 1].set()

        tasks = [asyncio.create_task(hop(i)) for i in range(len(events))]
        await settle()  # every task is now waiting on its event
        assert reached == []
        events[0].set()
        n = await settle()
        await asyncio.gather(*tasks)
        return reached, n

    reached, n = anyio.run(main, backend="asyncio")
    assert reached == list(range(10))
    assert 10 <= n < SETTLE_CHECKPOINTS


def test_an_idle_loop_settles_at_once_and_a_busy_one_at_the_limit() -> None:
    async def main() -> tuple[int, int]:
        idle = await settle()

        async def spin() -> None:
            while True:
                await asyncio.sleep(0)

        spinner = asyncio.create_task(spin())
        busy = await settle()
        spinner.cancel()
        return idle, busy

    assert anyio.run(main, backend="asyncio") == (1, SETTLE_CHECKPOINTS)


def test_on_trio_every_checkpoint_is_taken() -> None:
    assert anyio.run(settle, backend="trio") == SETTLE_CHECKPOINTS
