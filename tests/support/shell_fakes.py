"""Fake robot functions of known duration for the shell's tests, on Trio's virtual clock.

``fake(name, seconds)`` is an async shell function that takes exactly ``seconds`` (forever when its
element is persistent) and appends ``(virtual time, "name:start")`` to :data:`LOG` (``"name:reset"``
when its reset hook ran); ``shell_with`` builds a shell of such modules; ``timed_stream`` yields text
pieces at given virtual times, as an LLM streams them.
"""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable
from typing import Any

import anyio

from host.shell.context import CallContext
from host.shell.registry import Registry
from host.shell.shell import Shell
from host.shell.types import Module, shell_function

#: what the fakes did, in order: (virtual time s, "name:start" | "name:reset"); clear it per test
LOG: list[tuple[float, str]] = []


def fake(name: str, seconds: float, *, reset_seconds: float | None = None) -> Callable[..., Any]:
    """An async function that takes ``d`` seconds (default ``seconds``; forever when persistent) and logs."""

    async def reset() -> None:
        await anyio.sleep(reset_seconds or 0)
        LOG.append((anyio.current_time(), f"{name}:reset"))

    @shell_function(name=name, reset=reset if reset_seconds is not None else None)
    async def fn(ctx: CallContext, d: float = seconds) -> None:
        LOG.append((anyio.current_time(), f"{name}:start"))
        if ctx.persistent:
            await anyio.sleep_forever()
        await anyio.sleep(d)

    return fn


def shell_with(channels: dict[str, list[Any]], **kw: Any) -> Shell:
    """A shell whose modules are ``channel -> functions``."""
    return Shell(Registry([Module.from_functions(ch, *fns) for ch, fns in channels.items()]), **kw)


async def timed_stream(parts: list[tuple[float, str]]) -> AsyncIterator[str]:
    """Yield each text at its virtual time (relative to the stream's start)."""
    t0 = anyio.current_time()
    for at, text in parts:
        await anyio.sleep(max(0.0, t0 + at - anyio.current_time()))
        yield text
