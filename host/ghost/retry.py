"""Retries and timeouts shared by the HTTP ghosts (Anthropic, OpenAI-compatible).

Division of labour with the SDKs, so nothing is retried twice: the official
``openai`` and ``anthropic`` SDKs already retry the *request* (HTTP 408/409/429/5xx
and connection errors before any response body) ``max_retries`` times with
exponential backoff, honouring ``retry-after`` / ``retry-after-ms``. What they
cannot retry is a failure *inside* a 200 stream: an SSE ``error`` event
(``overloaded_error``, ``rate_limit_error``, ``api_error``), a dropped connection,
or a server that accepts the request but sends nothing. :func:`retrying_stream`
retries exactly those, and only while no text has been yielded yet (a retry after
text would repeat speech and calls). Request-level status errors the SDK has
already retried are marked ``sdk_retried`` and passed through.

The backoff formula is the SDKs' own (0.5 s x 2^n capped at 8 s, jitter -25 %),
so both layers back off alike; a ``retry_after_s`` carried by the error wins.
"""

from __future__ import annotations

import random
from collections.abc import AsyncIterator, Awaitable, Callable
from dataclasses import dataclass

import anyio

from host.ghost.base import GhostError

INITIAL_DELAY_S = 0.5
MAX_DELAY_S = 8.0


@dataclass(frozen=True)
class StreamLimits:
    """Timeouts and stream-level retries for one reply.

    ``first_token_s``: seconds from the request to the first text chunk;
    ``total_s``: seconds for the whole reply (``None``: unbounded);
    ``stream_retries``: extra attempts after a retryable failure before the first
    chunk (see the module docstring for what the SDK retries itself).
    """

    first_token_s: float | None = 60.0
    total_s: float | None = 600.0
    stream_retries: int = 2


def backoff_s(attempt: int, retry_after_s: float | None = None, rng: random.Random | None = None) -> float:
    """Seconds to wait before retry ``attempt`` (0-based): ``retry_after_s`` if given, else
    ``min(0.5 * 2**attempt, 8) * U(0.75, 1)`` (the anthropic/openai SDKs' formula)."""
    if retry_after_s is not None and retry_after_s >= 0:
        return min(retry_after_s, 60.0)
    base = min(INITIAL_DELAY_S * 2.0 ** min(attempt, 30), MAX_DELAY_S)
    return base * (1 - 0.25 * (rng or random).random())


async def retrying_stream(
    open_stream: Callable[[], AsyncIterator[str]],
    limits: StreamLimits,
    *,
    name: str,
    sleep: Callable[[float], Awaitable[None]] | None = None,
    clock: Callable[[], float] | None = None,
) -> AsyncIterator[str]:
    """Yield the chunks of ``open_stream()``, with the timeouts and retries of ``limits``.

    Raises :class:`GhostError` (``retryable=True`` for timeouts) on a first-token
    or overall timeout, and re-raises a failure once text has been yielded or the
    retries are used up. Each attempt's generator is closed before the next one
    and when the consumer stops early, so the HTTP stream is closed at once.
    """
    now = clock or anyio.current_time
    do_sleep = sleep or anyio.sleep
    start = now()
    attempt = 0
    while True:
        yielded = False
        gen = open_stream()
        try:
            while True:
                budget: float | None = None
                if limits.total_s is not None:
                    budget = limits.total_s - (now() - start)
                if not yielded and limits.first_token_s is not None:
                    first = limits.first_token_s - (now() - start)
                    budget = first if budget is None else min(budget, first)
                try:
                    with anyio.fail_after(max(budget, 0.0) if budget is not None else None):
                        chunk = await anext(gen)
                except StopAsyncIteration:
                    return
                except TimeoutError as err:
                    which = "first token" if not yielded else "whole reply"
                    limit = limits.first_token_s if not yielded else limits.total_s
                    timeout = GhostError(f"{name}: no {which} within {limit:g} s (timeout)", retryable=True)
                    timeout.final = True  # type: ignore[attr-defined]  # the budget is spent: no retry here
                    raise timeout from err
                yielded = True
                yield chunk
        except GhostError as err:
            if yielded or not err.retryable or getattr(err, "sdk_retried", False) or getattr(err, "final", False) or attempt >= limits.stream_retries:
                raise
            delay = backoff_s(attempt, getattr(err, "retry_after_s", None))
            attempt += 1
        finally:
            with anyio.move_on_after(5, shield=True):
                await gen.aclose()  # type: ignore[attr-defined]
        await do_sleep(delay)
