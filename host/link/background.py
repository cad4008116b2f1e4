"""The session's background loops (supervisor, heartbeat, time sync): one anyio task group in a task of its own.

:class:`BackgroundLoops` runs the loops in an :func:`anyio.create_task_group` under a
:class:`anyio.CancelScope` that :meth:`BackgroundLoops.stop` cancels; a loop that raises is logged,
never raised into the group (the others keep running).

Why one asyncio call remains here (``loop.create_task``): anyio has no unstructured spawn, by design,
but the session's public API opens in ``await BoardClient.connect(...)`` and closes in
``await client.close()`` from wherever the caller likes (an ``AsyncExitStack``, a ``finally``, another
``async with``). A task group entered in the caller's task would tie the caller's cancel scopes to the
session's lifetime (leaving an enclosing ``anyio.fail_after`` before ``close()`` raises "exiting a
cancel scope that isn't the current task's"), which ``asyncio.TaskGroup`` tolerated and anyio
rightly refuses. So the group lives in a task of its own. The link runs on anyio's asyncio backend
only (its transports sit on the asyncio loop: see :mod:`host.link.transports`), so this is no
loss of portability; everything the loops themselves await is anyio.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Callable

import anyio

__all__ = ["BackgroundLoops"]

log = logging.getLogger("host.link")

Loop = Callable[[], Awaitable[None]]


async def _guarded(loop: Loop) -> None:
    """Run a background loop; a bug in it is logged, never raised into the task group."""
    try:
        await loop()
    except Exception:
        log.exception("link: background task failed")


class BackgroundLoops:
    """Named loops run until :meth:`stop` (module docstring); start once per session."""

    def __init__(self) -> None:
        self._task: asyncio.Task[None] | None = None
        self._scope: anyio.CancelScope | None = None  # made in start(): anyio needs the running loop
        self._done: anyio.Event | None = None

    @property
    def running(self) -> bool:
        return self._task is not None and not self._task.done()

    def start(self, loops: dict[str, Loop]) -> None:
        """Start ``loops`` (name -> loop) in a task group of their own (call from the event loop)."""
        done = self._done = anyio.Event()
        scope = self._scope = anyio.CancelScope()

        async def run() -> None:
            try:
                with scope:
                    async with anyio.create_task_group() as tg:
                        for name, loop in loops.items():
                            tg.start_soon(_guarded, loop, name=name)
            finally:
                done.set()

        self._task = asyncio.get_running_loop().create_task(run(), name="link-background")

    async def stop(self) -> None:
        """Cancel the loops and wait until they ended (idempotent; a no-op when never started)."""
        if self._scope is not None:
            self._scope.cancel()
        if self._done is not None:
            await self._done.wait()
        self._task = None
