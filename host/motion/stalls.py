"""Stall injection for tests of lockstep determinism (off by default, zero cost when off).

``GHOSTSHELL_STALLS="seed=7,p=0.05,max_s=1.0"`` makes the host's control path stop at its stall points
(:func:`maybe_stall`: the telemetry driver before it tops up, a task woken by board time before it
reacts) with probability ``p`` (0..1) each, for a uniformly drawn 0..``max_s`` wall seconds (seeded by
``seed``, an int). Half the stalls block the whole event loop (``time.sleep``: heavy synchronous work,
as scene or mesh loading was), the other half only the task at the point (``anyio.sleep``: the rest of
the host keeps running, so anything that acts on wall time, not on what the board reported, shows).

A lockstep run must give the board the same message stream however the host is stalled
(``tests/run/test_lockstep_identity.py``, ``bench/bench_lockstep_identity.py``). Unset (the default):
:data:`STALLS` is None and every call site skips the hook with one ``is not None`` test.

A malformed value ends the process with one line on stderr and exit code 2 (bad input).
"""

from __future__ import annotations

import os
import random
import sys
import time

import anyio

__all__ = ["ENV", "STALLS", "Stalls", "maybe_stall", "parse"]

#: the environment variable that turns stall injection on
ENV = "GHOSTSHELL_STALLS"


class Stalls:
    """Seeded random stalls: at each :meth:`at` call, with probability ``p``, a stall of 0..``max_s`` s."""

    def __init__(self, seed: int, p: float, max_s: float) -> None:
        self.rng = random.Random(seed)
        self.p = p
        self.max_s = max_s
        #: stalls taken so far, and their total wall seconds
        self.count = 0
        self.total_s = 0.0

    async def at(self, point: str) -> None:
        """Maybe stall here (``point`` names the place, for debugging)."""
        if self.rng.random() >= self.p:
            return
        seconds = self.rng.uniform(0.0, self.max_s)
        blocking = self.rng.random() < 0.5
        self.count += 1
        self.total_s += seconds
        if blocking:
            time.sleep(seconds)  # the whole event loop stands still (heavy synchronous work)
        else:
            await anyio.sleep(seconds)  # only this task waits; the rest of the host runs on


def parse(text: str) -> Stalls:
    """``"seed=INT,p=FLOAT,max_s=FLOAT"`` (any order; p defaults to 0.05, max_s to 1.0, seed to 0) ->
    :class:`Stalls`. Raises ValueError naming what is wrong."""
    fields = {"seed": "0", "p": "0.05", "max_s": "1.0"}
    for part in filter(None, (p.strip() for p in text.split(","))):
        key, sep, value = part.partition("=")
        if not sep or key.strip() not in fields:
            raise ValueError(f"{ENV}: expected seed=INT,p=FLOAT,max_s=FLOAT, got {part!r}")
        fields[key.strip()] = value.strip()
    try:
        seed, p, max_s = int(fields["seed"]), float(fields["p"]), float(fields["max_s"])
    except ValueError:
        raise ValueError(f"{ENV}: seed must be an int, p and max_s numbers, got {text!r}") from None
    if not (0.0 <= p <= 1.0 and 0.0 <= max_s <= 60.0):
        raise ValueError(f"{ENV}: p must be in 0..1 and max_s in 0..60 s, got {text!r}")
    return Stalls(seed, p, max_s)


def _from_env() -> Stalls | None:
    text = os.environ.get(ENV, "").strip()
    if not text:
        return None
    try:
        return parse(text)
    except ValueError as e:
        print(f"ghostshell: {e}", file=sys.stderr)
        raise SystemExit(2) from None


#: the process's stall injector, None unless ``GHOSTSHELL_STALLS`` is set
STALLS: Stalls | None = _from_env()


async def maybe_stall(point: str) -> None:
    """Stall at ``point`` if injection is on (call sites test :data:`STALLS` first to cost nothing)."""
    if STALLS is not None:
        await STALLS.at(point)
