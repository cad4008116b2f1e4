"""``ScriptedGhost``: replays a fixed program the way an LLM streams its reply."""

from __future__ import annotations

import math
import random
from collections.abc import AsyncIterator, Awaitable, Callable

import anyio
import anyio.lowlevel

from host.ghost.base import Ghost, Message
from host.ghost.tokenize import tokenize

SleepFn = Callable[[float], Awaitable[object]]


class ScriptedGhost(Ghost):
    """Stream ``program`` in token-sized chunks at ``tokens_per_s`` with seeded jitter.

    Token *i* arrives after a gap of ``(1 + jitter * u_i) / tokens_per_s`` seconds,
    ``u_i`` uniform in [-1, 1] from ``random.Random(seed)``, so the mean rate is
    ``tokens_per_s`` and a run is reproducible. The first token also waits one gap
    (a minimal time to first token). ``tokens_per_s`` of ``0`` or ``inf`` streams
    as fast as possible (a scheduler checkpoint between chunks, no sleeping).
    ``sleep`` is injectable; tests pass nothing and run on Trio's ``MockClock``.
    The messages given to :meth:`stream` are ignored: the reply is the program.
    """

    name = "scripted"

    def __init__(
        self,
        program: str,
        tokens_per_s: float = 30.0,
        jitter: float = 0.2,
        seed: int = 0,
        sleep: SleepFn = anyio.sleep,
    ) -> None:
        if not isinstance(program, str):
            raise TypeError(f"program must be a str, not {type(program).__name__}")
        if math.isnan(tokens_per_s) or tokens_per_s < 0:
            raise ValueError(f"tokens_per_s must be >= 0 (0 or inf: as fast as possible), got {tokens_per_s}")
        if not 0.0 <= jitter <= 1.0:
            raise ValueError(f"jitter must be in [0, 1], got {jitter}")
        self.program = program
        self.tokens_per_s = tokens_per_s
        self.jitter = jitter
        self.seed = seed
        self._sleep = sleep
        self.tokens: list[str] = tokenize(program)

    @property
    def unpaced(self) -> bool:
        """True when streaming as fast as possible."""
        return self.tokens_per_s == 0 or math.isinf(self.tokens_per_s)

    def gaps(self) -> list[float]:
        """The inter-token gaps (seconds) one :meth:`stream` call will wait, in order."""
        if self.unpaced:
            return [0.0] * len(self.tokens)
        rng = random.Random(self.seed)
        period = 1.0 / self.tokens_per_s
        return [period * (1.0 + self.jitter * rng.uniform(-1.0, 1.0)) for _ in self.tokens]

    async def stream(self, messages: list[Message] | None = None) -> AsyncIterator[str]:
        """Yield the program's tokens, paced; concatenated they equal the program."""
        for token, gap in zip(self.tokens, self.gaps(), strict=True):
            if gap > 0.0:
                await self._sleep(gap)
            else:
                await anyio.lowlevel.checkpoint()
            yield token
